# The default shot made small for the pipeline tests: cells twice as large and a tenth of the strands, its first
# FRAMES frames (default 20: the dunk, the hold and most of the lift), named default_small. Dripping's thresholds are
# in units of the particles' nominal volume, 8 times larger here: they are divided by 8 so that drops keep the full
# shot's sizes in m^3. Usage: small_default.py DEFAULT_JSON OUT_JSON [FRAMES]
import json
import sys

s = json.load(open(sys.argv[1]))
s['shot']['name'] = 'default_small'
s['shot']['frames'] = [1, int(sys.argv[3]) if len(sys.argv) > 3 else 20]
for e in s['elements']:
    c = e['components']
    if 'Domain' in c:
        c['Domain']['voxel_size'] *= 2
    if 'Groom' in c:
        c['Groom']['count'] = max(1, c['Groom'].get('count', 100) // 10)
    if 'Dripping' in c:
        c['Dripping']['min_drop'] = c['Dripping'].get('min_drop', 0.5) / 8
        c['Dripping']['pool_release'] = c['Dripping'].get('pool_release', 1.0) / 8
json.dump(s, open(sys.argv[2], 'w'), indent=1)
