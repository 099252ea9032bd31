"""Issue 11: how small is the signal that separates a shortest route from the rest?

Value iteration on Warehouse-12x12-v0's MDP (SPEC.md rewards x 0.01, the PPO default's reward
scale; gamma 0.95) per item, over (cell, carrying). For every state on a shortest route it takes
the gap between the best shortest-route action's Q and the best other action's Q, and prints the
smallest gap per item. ``.venv/bin/python bench/investigations/action_gap_value_iteration.py``
(pure Python, a few minutes). Output: action_gap_value_iteration.txt.
"""
import numpy as np
from wrl_jax.envs.warehouse.maps import WAREHOUSE_12X12 as M
rows=[l.split() for l in M.strip().splitlines()]; N=len(rows)
shelf=np.array([[c=='#' for c in r] for r in rows])
find=lambda ch:[(i,j) for i in range(N) for j in range(N) if rows[i][j]==ch][0]
S,G=find('S'),find('G')
items=[ch for ch in "0123456789abcdefghij"]
moves=[(-1,0),(1,0),(0,-1),(0,1)]
def step(p,a):
    q=(p[0]+moves[a][0],p[1]+moves[a][1])
    if not(0<=q[0]<N and 0<=q[1]<N): return p,0.0
    if shelf[q]: return p,-10.0
    return q,0.0
def solve(item,gamma,scale=0.01):
    I=find(item)
    # V[stage, r, c]; stage 0 target item, 1 target goal
    V=np.zeros((2,N,N))
    for _ in range(400):
        Q=qvals(V,I,gamma)
        V=Q.max(-1)
    return qvals(V,I,gamma)*scale
def qvals(V,I,gamma):
    Q=np.full((2,N,N,4),-1e9)
    for st in (0,1):
        tgt=I if st==0 else G
        for r in range(N):
            for c in range(N):
                if shelf[r,c]: continue
                for a in range(4):
                    q,pen=step((r,c),a)
                    d=lambda x:abs(x[0]-tgt[0])+abs(x[1]-tgt[1])
                    rew=pen+2.0*(d((r,c))-d(q))
                    if st==0 and q==I: rew+=-0.5+50; Q[st,r,c,a]=rew+gamma*V[1,q[0],q[1]]
                    elif st==1 and q==G: rew+=200; Q[st,r,c,a]=rew
                    else: rew+=-0.5; Q[st,r,c,a]=rew+gamma*V[st,q[0],q[1]]
    return Q
from collections import deque
def bfs(src):
    D=np.full((N,N),10**6); D[src]=0; dq=deque([src])
    while dq:
        p=dq.popleft()
        for a in range(4):
            q,_=step(p,a)
            if q!=p and D[q]>D[p]+1: D[q]=D[p]+1; dq.append(q)
    return D
for gamma in (0.95,):
    out=[]
    for k,item in enumerate(items):
        I=find(item); Q=solve(item,gamma)
        DS,DI,DG=bfs(S),bfs(I),bfs(G)
        L=DS[I]+DI[G]
        # states on a shortest route, stage 0 and 1; gap between the best Q on-route and best off-route action
        gaps=[]
        for st,(dist_to,total_from) in ((0,(DI,None)),(1,(DG,None))):
            for r in range(N):
                for c in range(N):
                    if shelf[r,c]: continue
                    p=(r,c)
                    on = (DS[p]+DI[p]==DS[I]) if st==0 else (DI[p]+DG[p]==DI[G])
                    if not on or (st==0 and p==I) or (st==1 and p==G): continue
                    tgtD = DI if st==0 else DG
                    good=[a for a in range(4) if step(p,a)[0]!=p and tgtD[step(p,a)[0]]==tgtD[p]-1]
                    bad=[a for a in range(4) if a not in good]
                    gaps.append(Q[st,r,c,good].max()-Q[st,r,c,bad].max())
        out.append((k,item,int(L),min(gaps)))
    print(f"gamma {gamma}: min action gap on shortest routes (scaled return units):")
    print("  "+" ".join(f"{k}:{g:.3f}" for k,_,_,g in out))
