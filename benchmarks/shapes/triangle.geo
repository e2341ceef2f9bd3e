// Exercises sharp (60-degree) corners: an equilateral triangle of side 1.5. Each corner
// gives +1/4 (one quad meets there), leaving +1/4 to the interior: one valence-3 vertex,
// the classic three-quad split.
SetFactory("OpenCASCADE");
s = 1.5;
Point(1) = {0, 0, 0};
Point(2) = {s, 0, 0};
Point(3) = {s / 2, s * Sqrt(3) / 2, 0};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 1};
Curve Loop(1) = {1, 2, 3};
Plane Surface(1) = {1};
