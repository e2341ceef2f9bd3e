// Exercises a 270-degree concave corner: the L-shaped domain [0,2]^2 less [1,2]^2. Five
// convex corners (+1/4 each) and one concave (-1/4): no interior singularity needed; the
// concave corner's regular valence is 4.
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 2};
Rectangle(2) = {1, 1, 0, 1, 1};
BooleanDifference(3) = { Surface{1}; Delete; }{ Surface{2}; Delete; };
