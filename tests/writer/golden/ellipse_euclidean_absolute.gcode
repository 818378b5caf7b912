; printability test generated this file
; printability: nozzle = ellipse:major=0.8,minor=0.3
; printability: machine = ttr
; printability: rotary axis = A, degrees, period 180
; printability: feed policy = euclidean, E = absolute, bead model = rounded, filament = 1.75 mm
; printability: layers = 1, target area = 100.000 mm2, lost area = 1.500 mm2 (1.50 %)
; printability: layer z, target mm2, lost mm2, dropped moves, dropped mm, split moves
; printability: layer 0.200 100.0000 1.5000 0 0.000 0
G21 ; millimetres
G90 ; absolute XYZ
M82 ; absolute E
G92 E0
G1 X10 Y10 Z0.2 A-90 F9000
G1 A-180 F3600
G1 X20 E0.33849 F1800
G1 A-270 F3600
G1 Y20 E0.67698 F1800
G1 A-360 F3600
G1 X10 E1.01546 F1800
G1 A-450 F3600
G1 Y10 E1.35395 F1800
G1 E0.55395 F2100
G1 X30 Y30 A-495 F4252
G1 E1.35395 F2100
G1 X31 Y31 E1.40395 F1800
