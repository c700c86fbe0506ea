; A job that waits for its temperatures, as sliced jobs do.
G28
M140 S60
M104 S200
M190 S60 ; wait for the bed
M109 S200 ; wait for the hotend
G92 E0
G1 Z0.3 F600
G1 X50 Y50 E1.0 F3000
G1 X80 Y50 E2.0
G1 X80 Y80 E3.0
G1 X50 Y80 E4.0
G1 X50 Y50 E5.0
M104 S0
M140 S0
M400
