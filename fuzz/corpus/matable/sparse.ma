# a sparse table: one read per resultant
1 2 3
4,5 # the pair

6-10
12
