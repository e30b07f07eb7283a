# MA table 6 as counts per resultant, and a ranged form
1
2-3
4,5,6,7
8-15
16-31
32-63
