// A block with a through hole, its four vertical edges filleted (OpenCASCADE).
SetFactory("OpenCASCADE");
Box(1) = {0, 0, 0, 2, 1, 0.6};
Cylinder(2) = {1, 0.5, -0.1, 0, 0, 0.8, 0.25};
BooleanDifference(3) = {Volume{1}; Delete;}{Volume{2}; Delete;};
// the vertical edges of the block: those parallel to z at its corners
e() = Curve In BoundingBox{-0.01, -0.01, -0.01, 0.01, 0.01, 0.61};
e() += Curve In BoundingBox{1.99, -0.01, -0.01, 2.01, 0.01, 0.61};
e() += Curve In BoundingBox{-0.01, 0.99, -0.01, 0.01, 1.01, 0.61};
e() += Curve In BoundingBox{1.99, 0.99, -0.01, 2.01, 1.01, 0.61};
Fillet{3}{e()}{0.2}
