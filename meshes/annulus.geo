// The annulus of ufl_frames (ufl_frames.mesh.annulus): r_inner <= |x| <= r_outer,
// default 0.5 <= |x| <= 1, area 3 pi / 4. Same construction as the Python builder.
//
//   ufl_frames.mesh.load(comm, "meshes/annulus.geo", mesh_size)
//   gmsh meshes/annulus.geo -2          (stand-alone; h below is then the size)
SetFactory("OpenCASCADE");

DefineConstant[
  r_inner = {0.5, Name "Parameters/inner radius"},
  r_outer = {1.0, Name "Parameters/outer radius"},
  h       = {0.05, Name "Parameters/mesh size"}
];

Disk(1) = {0, 0, 0, r_outer};
Disk(2) = {0, 0, 0, r_inner};
BooleanDifference(3) = { Surface{1}; Delete; }{ Surface{2}; Delete; };

Physical Surface("domain", 1) = {3};
Physical Curve("boundary", 2) = Boundary{ Surface{3}; };

Mesh.MeshSizeMax = h;
