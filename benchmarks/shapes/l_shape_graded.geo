// The L-shape [0,2]^2 less [1,2]^2 refined towards its re-entrant corner (1, 1) over two
// decades (Distance/Threshold: 0.002 to 0.2): a graded file for benchmarks/sizes.py.
Point(1) = {0, 0, 0, 0.2}; Point(2) = {2, 0, 0, 0.2}; Point(3) = {2, 1, 0, 0.2};
Point(4) = {1, 1, 0, 0.002}; Point(5) = {1, 2, 0, 0.2}; Point(6) = {0, 2, 0, 0.2};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 5}; Line(5) = {5, 6};
Line(6) = {6, 1};
Curve Loop(1) = {1, 2, 3, 4, 5, 6}; Plane Surface(1) = {1};
Field[1] = Distance; Field[1].PointsList = {4};
Field[2] = Threshold; Field[2].InField = 1; Field[2].SizeMin = 0.002; Field[2].SizeMax = 0.2;
Field[2].DistMin = 0.0; Field[2].DistMax = 1.0;
Background Field = 2;
Mesh.MeshSizeExtendFromBoundary = 0;
