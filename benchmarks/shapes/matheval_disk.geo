// The unit disk with a MathEval size field growing from 0.01 on the left to 0.11 on the
// right: a graded file for benchmarks/sizes.py.
SetFactory("OpenCASCADE");
Disk(1) = {0, 0, 0, 1};
Field[1] = MathEval; Field[1].F = "0.06 + 0.05*x";
Background Field = 1;
Mesh.MeshSizeExtendFromBoundary = 0; Mesh.MeshSizeFromPoints = 0;
