import json,gzip,sys,statistics as st
W={}
for l in gzip.open(sys.argv[1],'rt'):
    r=json.loads(l); W[r['index']]=r
C={json.loads(l)['index']:json.loads(l) for l in open(sys.argv[2])}
mx=max(r['omega_J_m3'] or 0 for r in W.values())
errs=[];rows=[]
for i,c in C.items():
    w=W[i]; oc=c['omega_J_m3'] or 0; ow=w['omega_J_m3'] or 0
    d=abs(ow-oc)/max(oc,1e-300); errs.append(d)
    rows.append((d,i,oc,ow,abs(ow-oc)/mx,c['feasible']==w['feasible'],w['design']))
errs.sort(); n=len(errs)
print('n',n,'median %.2e p90 %.2e max %.2e'%(errs[n//2],errs[int(.9*n)],errs[-1]),'within 0.1%%: %d, 1%%: %d'%(sum(e<=1e-3 for e in errs),sum(e<=1e-2 for e in errs)),'feasibility agree',sum(r[5] for r in rows))
rows.sort(reverse=True)
for r in rows[:10]: print(' %d %s cold %.2f warm %.2f rel %.1f%% (of max %.2f%%)'%(r[1],{k:round(v,2) for k,v in r[6].items()},r[2],r[3],100*r[0],100*r[4]))
