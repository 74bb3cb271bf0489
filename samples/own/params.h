0 BEGIN PGM PARAMS MM
1 ; ilcnc own sample: Q parameters, a formula, a section repeat (CALL LBL REP)
2 ; and a conditional jump; same licence as ilcnc (GPL-3.0-or-later)
3 FN 0: Q1 = +10
4 Q2 = Q1 * 2 + SQRT ( 16 ) ; 24
5 FN 4: Q3 = +Q2 DIV +8
6 TOOL CALL 1 Z S10000
7 L X+0 Y+0 Z+5 R0 FMAX M3
8 L Z-1 F100
9 LBL 1
10 L IX+10 F300
11 CALL LBL 1 REP 2
12 L X+Q2 Y+Q1
13 FN 9: IF +Q3 EQU +3 GOTO LBL "done"
14 L X+999
15 LBL "done"
16 L Y+0
17 L Z+5 FMAX
18 M30
19 END PGM PARAMS MM
