// Exercises holes (genus): a 2 x 1 plate with three circular holes. Euler characteristic
// 1 - 3 = -2 and four 90-degree corners: the interior indices sum to -3, at least twelve
// -1/4 singularities (valence-5 vertices). Curved boundaries of three sizes.
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 2, 1};
Disk(2) = {0.45, 0.5, 0, 0.2};
Disk(3) = {1.1, 0.35, 0, 0.15};
Disk(4) = {1.55, 0.65, 0, 0.17};
BooleanDifference(5) = { Surface{1}; Delete; }{ Surface{2, 3, 4}; Delete; };
