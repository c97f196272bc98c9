import re,statistics as st
rows={}
for l in open("docs/shift/run32.log"):
    p=l.split()
    if "all" not in p: continue
    rev = "--reverse" in p
    t=p[0]; f=p[2] if rev else p[1]; s=p[3] if rev else p[2]
    m=re.findall(r"([\d.]+)/([\d.]+)/[\d.]+%",l)
    rows[(t,f,s)]=(float(m[0][0]),float(m[1][0]))
turns=sorted({k[0] for k in rows},key=int)
dp=[];da=[];cp=[];ca=[];sp=[];sa=[]
for t in turns:
    pairs=[s for s in "123" if (t,"cf4s",s) in rows and (t,"cf4e1chk",s) in rows]
    if not pairs: continue
    for s in pairs:
        a=rows[(t,"cf4e1chk",s)]; b=rows[(t,"cf4s",s)]
        dp.append(b[0]-a[0]); da.append(b[1]-a[1]); cp.append(a[0]);ca.append(a[1]);sp.append(b[0]);sa.append(b[1])
    c=[rows[(t,'cf4e1chk',s)] for s in pairs]; q=[rows[(t,'cf4s',s)] for s in pairs]
    print(t, "control %.1f/%.2f"%(st.mean(x[0] for x in c),st.mean(x[1] for x in c)), "spread %.1f/%.2f"%(st.mean(x[0] for x in q),st.mean(x[1] for x in q)))
print(len(dp),"pairs; control %.2f ± %.2f / %.2f ± %.2f; spread %.2f ± %.2f / %.2f ± %.2f"%(st.mean(cp),st.stdev(cp),st.mean(ca),st.stdev(ca),st.mean(sp),st.stdev(sp),st.mean(sa),st.stdev(sa)))
print("diff pos %.2f ± %.2f  att %.2f ± %.2f; spread better in %d/%d pos, %d/%d att"%(st.mean(dp),st.stdev(dp),st.mean(da),st.stdev(da),sum(x<0 for x in dp),len(dp),sum(x<0 for x in da),len(da)))
