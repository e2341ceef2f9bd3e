// A unit square whose corners ask for sizes 0.01, 0.03, 0.1 and 0.03 (point sizes only,
// interpolated by Gmsh from the boundary): a graded file for benchmarks/sizes.py.
Point(1) = {0, 0, 0, 0.01}; Point(2) = {1, 0, 0, 0.03};
Point(3) = {1, 1, 0, 0.1}; Point(4) = {0, 1, 0, 0.03};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
