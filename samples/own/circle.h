0 BEGIN PGM CIRCLE MM
1 ; ilcnc own sample: circles around CC - two half arcs, a full circle with the same
2 ; end point, a full circle without coordinates, a radius arc CR and a helix;
3 ; same licence as ilcnc (GPL-3.0-or-later)
4 TOOL CALL 1 Z S12000
5 L X+30.000 Y+0.000 Z+2.000 R0 FMAX M3
6 L Z-1.000 F500
7 CC X+0.000 Y+0.000
8 C X-30.000 Y+0.000 DR+ F2000
9 C X+30.000 Y+0.000 DR+
10 C X+30.000 Y+0.000 DR-
11 C DR+
12 CR X+0.000 Y+30.000 R+30.000 DR+
13 CR X+30.000 Y+0.000 R-30.000 DR+
14 CC IX-10.000 IY+0.000
15 C X+30.000 Y+0.000 Z-3.000 DR-
16 L Z+2.000 FMAX
17 M30
18 END PGM CIRCLE MM
