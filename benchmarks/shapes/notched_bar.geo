// Exercises notches: a 3 x 1 bar with a 60-degree V notch (depth 0.4) in its bottom side,
// a 300-degree tip between two 120-degree mouth corners, and a U notch (width 0.2, depth
// 0.35, semicircular end) in its top side, 90-degree mouth corners. Corners give +7/4 in
// all: the interior indices sum to -3/4 (three -1/4 singularities, valence 5).
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 3, 1};
// V notch: a triangle with its tip at (1.5, 0.4), reaching below the bar.
Point(101) = {1.5, 0.4, 0};
Point(102) = {1.5 - 0.5 * Tan(Pi / 6), -0.1, 0};
Point(103) = {1.5 + 0.5 * Tan(Pi / 6), -0.1, 0};
Line(101) = {101, 102};
Line(102) = {102, 103};
Line(103) = {103, 101};
Curve Loop(101) = {101, 102, 103};
Plane Surface(2) = {101};
// U notch: a slot reaching above the bar, ended by a half disc at y = 0.75.
Rectangle(3) = {2.1, 0.75, 0, 0.2, 0.35};
Disk(4) = {2.2, 0.75, 0, 0.1};
BooleanDifference(5) = { Surface{1}; Delete; }{ Surface{2, 3, 4}; Delete; };
