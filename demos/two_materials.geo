// A steel plate with a round rubber inclusion: two materials, named boundaries.
//
// Surfaces: 1 the plate less the disc ("steel"), 2 the disc ("rubber"); they share the
// circle (the interface). Curves: 4 the left side ("inlet"), 2 the right side ("outlet"),
// 1 and 3 the bottom and top ("wall"), 5-8 the circle ("interface").
//
//   ufl-frames mesh demos/two_materials.geo --out out_regions
//
// meshes it with quadrilaterals (quads.msh keeps the groups where the quad stage carries
// the regions); demos/demo_regions.py solves a Poisson problem on the quads with DOLFINx.

Point(1) = {0, 0, 0};
Point(2) = {2, 0, 0};
Point(3) = {2, 1, 0};
Point(4) = {0, 1, 0};
Line(1) = {1, 2};  // bottom wall
Line(2) = {2, 3};  // outlet
Line(3) = {3, 4};  // top wall
Line(4) = {4, 1};  // inlet

r = 0.3;
Point(5) = {1, 0.5, 0};  // the inclusion's centre
Point(6) = {1 + r, 0.5, 0};
Point(7) = {1, 0.5 + r, 0};
Point(8) = {1 - r, 0.5, 0};
Point(9) = {1, 0.5 - r, 0};
Circle(5) = {6, 5, 7};
Circle(6) = {7, 5, 8};
Circle(7) = {8, 5, 9};
Circle(8) = {9, 5, 6};

Curve Loop(1) = {1, 2, 3, 4};
Curve Loop(2) = {5, 6, 7, 8};
Plane Surface(1) = {1, 2};  // the plate with a hole
Plane Surface(2) = {2};     // the inclusion

Physical Surface("steel", 1) = {1};
Physical Surface("rubber", 2) = {2};
Physical Curve("inlet", 3) = {4};
Physical Curve("outlet", 4) = {2};
Physical Curve("wall", 5) = {1, 3};
Physical Curve("interface", 6) = {5, 6, 7, 8};
