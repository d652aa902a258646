import numpy as np, collections
from skimage import measure
from isoconvert.extract import trilinear as T

def topo(tris):
    """components, euler, boundary loops of a triangle list over hashable vertex keys"""
    tris=[tuple(t) for t in tris]
    if not tris: return (0,0,0)
    verts=sorted({v for t in tris for v in t}, key=repr)
    idx={v:i for i,v in enumerate(verts)}
    par=list(range(len(verts)))
    def f(x):
        while par[x]!=x: par[x]=par[par[x]]; x=par[x]
        return x
    edges=collections.Counter()
    for t in tris:
        a,b,c=(idx[v] for v in t)
        par[f(a)]=f(b); par[f(b)]=f(c)
        for u,v in ((a,b),(b,c),(c,a)): edges[(min(u,v),max(u,v))]+=1
    comps=len({f(i) for i in range(len(verts))})
    E=len(edges); chi=len(verts)-E+len(tris)
    bnd=[e for e,k in edges.items() if k==1]
    assert all(k<=2 for k in edges.values()), "nonmanifold edge"
    # boundary loops
    p2=list(range(len(verts)))
    def g(x):
        while p2[x]!=x: p2[x]=p2[p2[x]]; x=p2[x]
        return x
    bv=set()
    for u,v in bnd: p2[g(u)]=g(v); bv|={u,v}
    loops=len({g(x) for x in bv})
    return comps, chi, loops

def ours(values, level):
    tris=[]
    for k,(pt,inner) in enumerate(T.trilinear_cube(values, level)):
        for t in pt:
            tris.append(tuple(v if v<T.INNER else (k,v) for v in t))
    return topo(tris)

def fine(values, level, n=48):
    x=np.linspace(0,1,n)
    X,Y,Z=np.meshgrid(x,x,x,indexing='ij')
    v=values
    F=sum(v[c]*np.where(c&1,X,1-X)*np.where(c>>1&1,Y,1-Y)*np.where(c>>2&1,Z,1-Z) for c in range(8))
    if F.min()>=level or F.max()<level: return (0,0,0)
    vs,fs,_,_=measure.marching_cubes(F,level,method='lorensen')
    # weld by position (skimage shares vertices already)
    return topo([tuple(t) for t in fs])

def margin(values, level):
    """min distance of any face/body saddle value (in range) from level, relative"""
    return None
