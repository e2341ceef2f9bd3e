// Exercises a spline boundary with a sharp corner: a NACA 0012 airfoil (chord 1, closed
// trailing edge, splines through 25 cosine-spaced points per side) inside the box
// [-0.5, 1.5] x [-0.5, 0.5]. The trailing edge's ~344-degree angle (index -1/2) and the
// box's corners leave -1/2 to the interior: two -1/4 singularities (valence 5).
SetFactory("OpenCASCADE");
N = 24;
t = 0.12;
// Points from the trailing edge over the top to the leading edge and back underneath;
// the two splines meet on the lower side at x ~ 0.15 (a kink of a fraction of a degree),
// so that the leading edge lies inside a spline and is smooth.
K = 6;  // the lower point where the splines meet
te = newp;
Point(te) = {1, 0, 0};
nose[] = {};
tail[] = {te};
For i In {N - 1 : 0 : -1}  // upper side, trailing edge to leading edge
  b = Pi * i / N;
  x = 0.5 * (1 - Cos(b));
  p = newp;
  Point(p) = {x, 5 * t * (0.2969 * Sqrt(x) - 0.1260 * x - 0.3516 * x^2 + 0.2843 * x^3 - 0.1036 * x^4), 0};
  tail[] += p;
EndFor
For i In {1 : N - 1}  // lower side, leading edge to trailing edge
  b = Pi * i / N;
  x = 0.5 * (1 - Cos(b));
  p = newp;
  Point(p) = {x, -5 * t * (0.2969 * Sqrt(x) - 0.1260 * x - 0.3516 * x^2 + 0.2843 * x^3 - 0.1036 * x^4), 0};
  If (i < K)
    tail[] += p;
  ElseIf (i == K)
    tail[] += p;
    nose[] += p;
  Else
    nose[] += p;
  EndIf
EndFor
nose[] += te;
Spline(1) = tail[];  // trailing edge, over the top, round the leading edge, to the split
Spline(2) = nose[];  // the split to the trailing edge, underneath
Curve Loop(1) = {1, 2};
Plane Surface(1) = {1};
Rectangle(2) = {-0.5, -0.5, 0, 2, 1};
BooleanDifference(3) = { Surface{2}; Delete; }{ Surface{1}; Delete; };
