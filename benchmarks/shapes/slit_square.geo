// Exercises a slit: the unit square cut from the middle of its left side to its centre,
// one surface whose boundary loop runs along the slit and back (the same curve twice). The
// mesh is cut open there; the tip is a 360-degree corner.
Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};
Point(5) = {0, 0.5, 0}; Point(6) = {0.5, 0.5, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5};
Line(5) = {5, 6}; Line(6) = {5, 1};
Curve Loop(1) = {1, 2, 3, 4, 5, -5, 6};
Plane Surface(1) = {1};
