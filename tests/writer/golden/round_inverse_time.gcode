; printability test generated this file
; printability: nozzle = ellipse:major=0.8,minor=0.3
; printability: machine = ttr
; printability: rotary axis = none (round nozzle)
; printability: feed policy = inverse-time, E = relative, bead model = rounded, filament = 1.75 mm
; printability: layers = 1, target area = 100.000 mm2, lost area = 1.500 mm2 (1.50 %)
; printability: layer z, target mm2, lost mm2, dropped moves, dropped mm, split moves
; printability: layer 0.200 100.0000 1.5000 0 0.000 0
G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
G93 ; inverse-time feed: F is 1/minutes of each move
G0 X10 Y10 Z0.2 F3600
G1 X20 E0.33849 F180
G1 Y20 E0.33849 F180
G1 X10 E0.33848 F180
G1 Y10 E0.33849 F180
G1 E-0.8 F2625
G0 X30 Y30 F318.1981
G1 E0.8 F2625
G1 X31 Y31 E0.05 F1272.7922
G94 ; feed in units per minute
