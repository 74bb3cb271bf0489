(ilcnc own sample: the 50 mm square in incremental mode, Fanuc style; same licence as ilcnc)
%
O1000
N10 G21 G17 G90
N20 G0 X0. Y0. Z5.
N30 G1 Z0. F1000.
N40 G91 G1 X50. F3000.
N50 Y50.
N60 X-50.
N70 Y-50.
N80 G90 G0 Z5.
N90 M30
%
