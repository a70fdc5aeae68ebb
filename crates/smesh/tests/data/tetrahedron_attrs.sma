# nverts 4                   
# nfaces 4                   
# bb_min 0e0 0e0 0e0                                       
# bb_max 1e0 1e0 1e0                                       
# vertex_attributes t grad
# tetrahedron
v 0 0 0 0.5 1
v 1 0 0 1.5 2
v 0 1 0 -2.5 0.25
f 1 3 2
v 0 0 1 3 1024
f 1 2 4
f -4 4 3
f -3 -2 -1
