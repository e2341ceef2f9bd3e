// Exercises a smooth closed curve without corners: a disc of radius 0.8. The boundary
// turns by 360 degrees with no corner to absorb it: four +1/4 singularities (valence-3
// vertices) inside.
SetFactory("OpenCASCADE");
Disk(1) = {0, 0, 0, 0.8};
