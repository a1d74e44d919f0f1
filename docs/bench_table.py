#!/usr/bin/env python3
# canopy: the README's "The latest run" table from a `canopy bench --csv`
# file: per scene, each builder's median at 1 and 2 threads, the fastest
# rounds, the speedups (ratio of medians; the per-round ratio's median), then
# each builder's 2-thread speedup over the round's ideal (the core check).
# Usage: python3 docs/bench_table.py docs/bench-<commit>.csv
import csv, collections, sys
path=sys.argv[1]
rows=list(csv.DictReader(open(path)))
order=['sequential','omp_levels','omp_queues','omp_tasks','tbb','embree_scene','embree_builder']
names={'/work/shared/scenes/dragon_vrip_res2.obj':'dragon_vrip_res2','/work/shared/scenes/cow.obj':'cow'}
def fmt(v):
    v=float(v)
    if v>=100: return '%d'%round(v)
    if v>=10: return '%.1f'%v
    if v>=1: return '%.2f'%v
    return '%.3f'%v
by=collections.OrderedDict()
for r in rows: by.setdefault(r['scene'],{}).setdefault(int(r['threads']),{})[r['builder']]=r
out=['| scene | threads | sequential | omp_levels | omp_queues | omp_tasks | tbb | Embree scene | Embree rtcBuildBVH |','|---|---:|---:|---:|---:|---:|---:|---:|---:|']
ideal=[]
for sc,d in by.items():
    n=int(d[1]['sequential']['triangles'])
    label='`%s` (%s)'%(names.get(sc,sc),f'{n:,}')
    out.append('| %s | 1 | %s |'%(label,' | '.join(fmt(d[1][b]['median_ms']) for b in order)))
    out.append('|  | 2 | %s |'%(' | '.join(fmt(d[2][b]['median_ms']) for b in order)))
    out.append('| | fastest round, 1 / 2 threads | %s |'%(' | '.join(fmt(d[1][b]['min_ms'])+' / '+fmt(d[2][b]['min_ms']) for b in order)))
    sp=['']+['%.2f× (%.2f×)'%(float(d[2][b]['speedup_vs_T1']),float(d[2][b]['speedup_vs_T1_per_round'])) for b in order[1:]]
    out.append('| | speedup (medians; per round) | | %s |'%(' | '.join(sp[1:])))
    ideal.append((names.get(sc,sc),[d[2][b]['speedup_over_ideal_per_round'] for b in order]))
print('\n'.join(out))
print()
for s,v in ideal: print(s, ' / '.join('%.2f'%float(x) for x in v))
