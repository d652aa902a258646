import sys; sys.path.insert(0, __import__('os').path.dirname(__file__))
import numpy as np
from fine_sampling import *
rng=np.random.default_rng(int(sys.argv[1]) if len(sys.argv)>1 else 0)
bad=0; n=0
for it in range(3000):
    v=rng.uniform(-1,1,size=8)
    config=sum(1<<i for i in range(8) if v[i]>=0)
    if not T.needs_interior_test(config): continue
    n+=1
    a=ours(v,0.0); b=fine(v,0.0,40); c=fine(v,0.0,81)
    if b!=c: continue  # fine sampling unresolved
    if a!=b:
        bad+=1
        if bad<6: print("MISMATCH", list(np.round(v,4)), a, b)
print("tested",n,"bad",bad)
