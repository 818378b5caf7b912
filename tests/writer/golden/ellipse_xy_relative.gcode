; printability test generated this file
; printability: nozzle = ellipse:major=0.8,minor=0.3
; printability: machine = ttr
; printability: rotary axis = C, degrees, period 180
; printability: feed policy = xy, E = relative, bead model = rounded, filament = 1.75 mm
; printability: layers = 1, target area = 100.000 mm2, lost area = 1.500 mm2 (1.50 %)
; printability: layer z, target mm2, lost mm2, dropped moves, dropped mm, split moves
; printability: layer 0.200 100.0000 1.5000 0 0.000 0
G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
G1 X10 Y10 Z0.2 C-90 F9000
G1 C-180 F3600
G1 X20 E0.33849 F1800
G1 C-270 F3600
G1 Y20 E0.33849 F1800
G1 C-360 F3600
G1 X10 E0.33848 F1800
G1 C-450 F3600
G1 Y10 E0.33849 F1800
G1 E-0.8 F2100
G1 X30 Y30 C-495 F9000
G1 E0.8 F2100
G1 X31 Y31 E0.05 F1800
