// The 'piano' of ufl_frames (ufl_frames.mesh.piano): a grand-piano outline
// whose boundary-aligned cross field has one +1/4 singularity on the left (under
// the rounded tail) and one -1/4 on the right (beside the concave bentside).
// See README.md beside this file. Same construction as the Python builder.
//
//   ufl-frames / ufl_frames.mesh.load(comm, "meshes/piano.geo", mesh_size)
//   gmsh meshes/piano.geo -2            (stand-alone; h below is then the size)
SetFactory("OpenCASCADE");

DefineConstant[
  w  = {2.0, Name "Parameters/width"},
  H  = {1.2, Name "Parameters/height"},
  r1 = {0.6, Name "Parameters/concave radius (bentside, top right)"},
  r2 = {0.8, Name "Parameters/convex radius (tail, top left)"},
  h  = {0.05, Name "Parameters/mesh size"}
];

Point(1) = {0, 0, 0};          // keyboard, bass end
Point(2) = {w, 0, 0};          // keyboard, treble end
Point(3) = {w, H - r1, 0};     // top of the treble cheek
Point(4) = {w - r1, H, 0};     // end of the concave bentside
Point(5) = {r2, H, 0};         // start of the convex tail
Point(6) = {0, H - r2, 0};     // end of the tail, top of the bass side
Point(7) = {w, H, 0};          // centre of the concave arc
Point(8) = {r2, H - r2, 0};    // centre of the convex arc

Line(1) = {1, 2};              // keyboard
Line(2) = {2, 3};              // treble cheek
Circle(3) = {3, 7, 4};         // concave bentside
Line(4) = {4, 5};              // top
Circle(5) = {5, 8, 6};         // convex tail
Line(6) = {6, 1};              // bass side

Curve Loop(1) = {1, 2, 3, 4, 5, 6};
Plane Surface(1) = {1};
Recursive Delete { Point{7, 8}; }

Physical Surface("domain", 1) = {1};
Physical Curve("boundary", 2) = {1, 2, 3, 4, 5, 6};

Mesh.MeshSizeMax = h;
