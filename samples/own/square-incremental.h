BEGIN PGM SQINC MM
; ilcnc own sample: the 50 mm square in incremental words (IX/IY), comma decimals,
; no block numbers, CRLF line ends and no final newline; same licence as ilcnc (GPL-3.0-or-later)
TOOL CALL 1 Z S12000
L X+10,000 Y+10,000 Z+5,000 R0 FMAX M3
L Z+0,000 F1000
L IX+50,000 F3000
L IY+50,000
L IX-50,000
L IY-50,000  
L IZ+5,000 FMAX
END PGM SQINC MM