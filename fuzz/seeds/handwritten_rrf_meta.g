; RepRapFirmware meta commands and quoted strings
M587 S"net ""x""" P"pass;word"
var depth = 2.5
if move.axes[2].homed
  G1 Z{var.depth} F600
else
  M291 P"home Z first" S2
while iterations < 3
  G1 X{iterations * 10}
echo "done"
M117 "(not a comment)"
G1 X1e400
G1 Xnan Y-inf
G0 X1 X2
G2 X10 Y0 I5 R5
