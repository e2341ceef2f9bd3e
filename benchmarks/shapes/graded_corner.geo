// A 2 x 1 rectangle refined towards its corner (0, 1) by a Distance/Threshold size field
// (sizes 0.01 to 0.1, one decade): a graded file for benchmarks/sizes.py.
Point(1) = {0, 0, 0, 0.1}; Point(2) = {2, 0, 0, 0.1};
Point(3) = {2, 1, 0, 0.1}; Point(4) = {0, 1, 0, 0.01};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Field[1] = Distance; Field[1].PointsList = {4};
Field[2] = Threshold; Field[2].InField = 1; Field[2].SizeMin = 0.01; Field[2].SizeMax = 0.1;
Field[2].DistMin = 0.05; Field[2].DistMax = 1.0;
Background Field = 2;
