SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 1, 1};
Rectangle(2) = {1, 0, 0, 1, 1};
Disk(3) = {0.5, 0.5, 0, 0.2};
BooleanFragments{ Surface{1}; Delete; }{ Surface{2,3}; Delete; }
Point(20) = {1.5, 0.5, 0};
Point(21) = {1.2, 0.2, 0}; Point(22) = {1.8, 0.3, 0};
Line(30) = {21, 22};
Curve{30} In Surface{2};
Point{20} In Surface{2};
Physical Surface("left", 7) = {4};
Physical Surface("disk") = {3};
Physical Curve("inlet", 11) = {1};
