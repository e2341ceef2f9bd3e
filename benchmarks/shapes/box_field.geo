// A 2 x 1 rectangle with a Box field: size 0.015 inside [0.8, 1.2] x [0, 1], 0.1 outside,
// with a 0.3 wide transition: a graded file for benchmarks/sizes.py.
Point(1) = {0, 0, 0, 0.1}; Point(2) = {2, 0, 0, 0.1};
Point(3) = {2, 1, 0, 0.1}; Point(4) = {0, 1, 0, 0.1};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Field[1] = Box; Field[1].VIn = 0.015; Field[1].VOut = 0.1;
Field[1].XMin = 0.8; Field[1].XMax = 1.2; Field[1].YMin = -1; Field[1].YMax = 2;
Field[1].Thickness = 0.3;
Background Field = 1;
Mesh.MeshSizeExtendFromBoundary = 0; Mesh.MeshSizeFromPoints = 0;
