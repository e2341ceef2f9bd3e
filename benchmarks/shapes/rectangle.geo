// Exercises the trivial case: a 2 x 1 rectangle, four 90-degree corners, no interior
// singularity needed (a structured grid is the best quad mesh: no irregular vertex).
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
