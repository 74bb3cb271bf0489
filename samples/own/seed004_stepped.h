0 BEGIN PGM SEED004_STEPPED MM
1 ; ilcnc own sample: the stepped-workpiece cut of seed 004 (Ward, Ozkirimli, Jones,
2 ; Procedia CIRP 2021): Al 7075-T6 block 236 x 30 x 66 mm whose stock face steps give
3 ; 75 / 50 / 25 % radial immersion (9 / 6 / 3 mm) of a 12 mm two-flute carbide end mill;
4 ; straight up-milling cut along +Y (M3, material on the left), axial depth 8 mm,
5 ; 2016 rpm (76.0 m/min), F403.4 (0.100 mm/tooth), L end points every 2 mm.
6 ; Finished wall at X+21, tool centre X+27 (R0: the path is the tool centre).
7 ; Stock: seed004_stepped_omi.csv. Same licence as ilcnc (GPL-3.0-or-later)
8 BLK FORM 0.1 Z X+0 Y+0 Z-66
9 BLK FORM 0.2 X+30 Y+236 Z+0
10 TOOL CALL 1 Z S2016
11 L Z+50 R0 FMAX M3
12 L X+27 Y-8 FMAX
13 ; rapid to depth in the air, 2 mm before the block's end face (tool edge at Y-2)
14 L Z-8 FMAX
15 L Y+0 F403.4
16 L Y+2
17 L Y+4
18 L Y+6
19 L Y+8
20 L Y+10
21 L Y+12
22 L Y+14
23 L Y+16
24 L Y+18
25 L Y+20
26 L Y+22
27 L Y+24
28 L Y+26
29 L Y+28
30 L Y+30
31 L Y+32
32 L Y+34
33 L Y+36
34 L Y+38
35 L Y+40
36 L Y+42
37 L Y+44
38 L Y+46
39 L Y+48
40 L Y+50
41 L Y+52
42 L Y+54
43 L Y+56
44 L Y+58
45 L Y+60
46 L Y+62
47 L Y+64
48 L Y+66
49 L Y+68
50 L Y+70
51 L Y+72
52 L Y+74
53 L Y+76
54 L Y+78
55 L Y+80
56 L Y+82
57 L Y+84
58 L Y+86
59 L Y+88
60 L Y+90
61 L Y+92
62 L Y+94
63 L Y+96
64 L Y+98
65 L Y+100
66 L Y+102
67 L Y+104
68 L Y+106
69 L Y+108
70 L Y+110
71 L Y+112
72 L Y+114
73 L Y+116
74 L Y+118
75 L Y+120
76 L Y+122
77 L Y+124
78 L Y+126
79 L Y+128
80 L Y+130
81 L Y+132
82 L Y+134
83 L Y+136
84 L Y+138
85 L Y+140
86 L Y+142
87 L Y+144
88 L Y+146
89 L Y+148
90 L Y+150
91 L Y+152
92 L Y+154
93 L Y+156
94 L Y+158
95 L Y+160
96 L Y+162
97 L Y+164
98 L Y+166
99 L Y+168
100 L Y+170
101 L Y+172
102 L Y+174
103 L Y+176
104 L Y+178
105 L Y+180
106 L Y+182
107 L Y+184
108 L Y+186
109 L Y+188
110 L Y+190
111 L Y+192
112 L Y+194
113 L Y+196
114 L Y+198
115 L Y+200
116 L Y+202
117 L Y+204
118 L Y+206
119 L Y+208
120 L Y+210
121 L Y+212
122 L Y+214
123 L Y+216
124 L Y+218
125 L Y+220
126 L Y+222
127 L Y+224
128 L Y+226
129 L Y+228
130 L Y+230
131 L Y+232
132 L Y+234
133 L Y+236
134 L Y+244
135 L Z+50 FMAX
136 M30
137 END PGM SEED004_STEPPED MM
