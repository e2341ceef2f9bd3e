// Exercises several surfaces with spline walls and a thin zone: the upper half of a
// combustion chamber (the axis is y = 0): an inlet duct (x 0..1), the chamber (x 1..3)
// whose wall rises along two splines, a converging-diverging nozzle (x 3..4.5, a spline
// wall with its throat at x = 3.8), and a cooling liner 0.06 thick over the chamber's
// upper wall (its lower side the chamber's wall spline, its upper side a second spline).
// Four surfaces sharing three curves (interfaces), eight splines in all.
Point(1) = {0, 0, 0};    Point(2) = {1, 0, 0};     Point(3) = {3, 0, 0};
Point(4) = {4.5, 0, 0};  Point(5) = {4.5, 0.6, 0}; Point(6) = {3, 0.75, 0};
Point(7) = {1.3, 0.7, 0}; Point(8) = {1, 0.3, 0};   Point(9) = {0, 0.3, 0};
Point(10) = {3, 0.81, 0}; Point(11) = {1.3, 0.76, 0};
// spline control points
Point(20) = {1.12, 0.52, 0};
Point(21) = {1.7, 0.8, 0};  Point(22) = {2.4, 0.8, 0};
Point(23) = {3.45, 0.42, 0}; Point(24) = {3.8, 0.3, 0}; Point(25) = {4.15, 0.42, 0};
Point(26) = {1.7, 0.86, 0}; Point(27) = {2.4, 0.86, 0};
Line(1) = {1, 2};   // axis under the duct
Line(2) = {2, 3};   // axis under the chamber
Line(3) = {3, 4};   // axis under the nozzle
Line(4) = {4, 5};   // outlet
Spline(5) = {5, 25, 24, 23, 6};    // nozzle wall
Spline(6) = {6, 22, 21, 7};        // chamber wall (the liner's lower side)
Spline(7) = {7, 20, 8};            // chamber shoulder
Line(8) = {8, 9};   // duct wall
Line(9) = {9, 1};   // inlet
Line(10) = {2, 8};  // duct | chamber
Line(11) = {3, 6};  // chamber | nozzle
Line(12) = {6, 10}; // liner end
Spline(13) = {10, 27, 26, 11};     // liner's upper side
Line(14) = {11, 7}; // liner end
Curve Loop(1) = {1, 10, 8, 9};
Curve Loop(2) = {2, 11, 6, 7, -10};
Curve Loop(3) = {3, 4, 5, -11};
Curve Loop(4) = {-6, 12, 13, 14};
Plane Surface(1) = {1};  // duct
Plane Surface(2) = {2};  // chamber
Plane Surface(3) = {3};  // nozzle
Plane Surface(4) = {4};  // liner
Physical Surface("duct", 1) = {1};
Physical Surface("chamber", 2) = {2};
Physical Surface("nozzle", 3) = {3};
Physical Surface("liner", 4) = {4};
Physical Curve("inlet", 5) = {9};
Physical Curve("outlet", 6) = {4};
Physical Curve("axis", 7) = {1, 2, 3};
Physical Curve("walls", 8) = {5, 7, 8, 12, 13, 14};
