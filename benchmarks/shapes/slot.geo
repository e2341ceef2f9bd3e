// Exercises a feature thinner than the mesh size: a 2 x 1 rectangle with a narrow slot
// (width 0.04, depth 0.6) cut down from the middle of its top side. Two 90-degree mouth
// corners and two 270-degree corners at the slot's bottom cancel: no interior
// singularity is needed.
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
Rectangle(2) = {0.98, 0.4, 0, 0.04, 0.7};
BooleanDifference(3) = { Surface{1}; Delete; }{ Surface{2}; Delete; };
