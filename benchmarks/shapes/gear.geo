// Exercises curved and concave boundaries: a gear, a disc of radius 1 with ten flat-topped
// teeth (width 0.22, height 0.2) around a hub hole of radius 0.35. Twenty 90-degree tooth
// tips and twenty ~264-degree roots cancel, the Euler characteristic is 0: no interior
// singularity is needed.
SetFactory("OpenCASCADE");
N = 10;
R = 1.0;
H = 0.2;
W = 0.22;
Disk(1) = {0, 0, 0, R};
For i In {0 : N - 1}
  Rectangle(10 + i) = {R - 0.1, -W / 2, 0, H + 0.1, W};
  Rotate {{0, 0, 1}, {0, 0, 0}, 2 * Pi * i / N} { Surface{10 + i}; }
EndFor
BooleanUnion(100) = { Surface{1}; Delete; }{ Surface{10 : 10 + N - 1}; Delete; };
Disk(200) = {0, 0, 0, 0.35};
BooleanDifference(300) = { Surface{100}; Delete; }{ Surface{200}; Delete; };
