# nverts 7                   
# nfaces 5                   
# bb_min 0e0 0e0 0e0                                       
# bb_max 3e0 2.5e0 6.25e-1                                 
# isostream 0.1.0
# a vertex with NaN and inf coordinates
v nan 0 inf
v 2.0001 2 0
v 3 0 0.4375
f 1 2 3
v 3 1.75 0
f -1 -2 2
v 0 2.5 0
v 1 2.25 0
f -2 6 1
v 2 2.0001 0
f 1 7 -6
f -2 -1 -7
