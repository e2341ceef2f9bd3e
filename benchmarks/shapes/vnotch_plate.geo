// Exercises a narrow notch with holes: a 4 x 1 plate with a V-notch 0.002 wide at its
// mouth and 0.3 deep cut up from the middle of its bottom side, and three circular holes
// (one surface: the notch's sides face each other closer than most triangles are wide).
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 4, 1};
Point(101) = {1.999, 0, 0}; Point(102) = {2, 0.3, 0}; Point(103) = {2.001, 0, 0};
Point(104) = {2.001, -0.1, 0}; Point(105) = {1.999, -0.1, 0};
Line(101) = {101, 102}; Line(102) = {102, 103}; Line(103) = {103, 104};
Line(104) = {104, 105}; Line(105) = {105, 101};
Curve Loop(101) = {101, 102, 103, 104, 105};
Plane Surface(101) = {101};
Disk(2) = {0.7, 0.5, 0, 0.15};
Disk(3) = {3.3, 0.5, 0, 0.15};
Disk(4) = {2.0, 0.75, 0, 0.1};
BooleanDifference(10) = {Surface{1}; Delete;}{Surface{101, 2, 3, 4}; Delete;};
