# Collision elements (scene element `collision`): written as collision elements, the hair's collision behaviour is
# the one its CollisionGroup and CollisionResponse give (the frame caches hold the same numbers, bit for bit: only the
# scene key differs), on tests/data/hair_small.json (one element, self collision) and on two elements whose masks let
# one touch itself and the other but not the other itself; dropping the collision element between them changes the
# second's strands (the elements are what decides); a response's damping bakes and changes the result. A cloth panel's
# self contact written as a vertex_face collision element is its ClothMaterial.self_contact, bit for bit, and a panel
# no collision element lists makes no self contact. Bad collision elements exit 2 naming the element, the field and
# the fix, with no frame written.
source "$(dirname "$0")/lib.sh"
S="$WORK/scenes"
mkdir -p "$S"

# differ A B SHOT FRAME DATASET: the dataset differs between the two bakes at that frame
differ() { [ "$(h5 "$(printf '%s/%s/bake/frame.%04d.h5' "$1" "$3" "$4")" "$5")" != \
             "$(h5 "$(printf '%s/%s/bake/frame.%04d.h5' "$2" "$3" "$4")" "$5")" ]; }
sum_key() { grep -o "\"$2\":[0-9]*" "$1" | awk -F: '{ s += $2 } END { print s + 0 }'; }

python3 - "$ROOT" "$S" <<'PY'
import copy, json, sys
root, S = sys.argv[1], sys.argv[2]
def absolute(s):
    for e in s['elements']:
        for c in e['components'].values():
            for k, v in list(c.items()):
                if isinstance(v, str) and v.startswith('../../assets'): c[k] = root + v[5:]
    return s
def dump(s, name): json.dump(s, open(f'{S}/{name}.json', 'w'), indent=1)
# 1. hair_small as it is, and with its CollisionResponse moved into a collision element
base = absolute(json.load(open(f'{root}/tests/data/hair_small.json')))
base.pop('mesh'); base.pop('render')
dump(base, 'one_short')
one = copy.deepcopy(base)
resp = one['elements'][0]['components'].pop('CollisionResponse')
one['elements'].append({'name': 'fur_self', 'type': 'collision', 'components': {
    'Collision': {'members': ['fur'], 'method': 'edge_edge'}, 'CollisionResponse': resp}})
dump(one, 'one_elem')
# 2. two grooms: a touches itself and b, b does not touch itself
fur, head = base['elements']
a = copy.deepcopy(fur); a['name'] = 'fur_a'; a['components'].pop('CollisionResponse')
b = copy.deepcopy(fur); b['name'] = 'fur_b'; b['components'].pop('CollisionResponse')
b['components']['Groom'].update(seed=7, length=0.06)
r = {'stiffness': 20, 'friction': 0.3, 'thickness': 0.001}
two = {'shot': dict(base['shot'], name='two', frames=[1, 4]), 'elements': [a, b, head]}
short = copy.deepcopy(two)
short['elements'][0]['components'].update(CollisionGroup={'group': 0, 'collides_with': 2, 'self_collision': True},
                                          CollisionResponse=dict(r))
short['elements'][1]['components'].update(CollisionGroup={'group': 1, 'collides_with': 1, 'self_collision': False},
                                          CollisionResponse=dict(r))
dump(short, 'two_short')
elem = copy.deepcopy(two)
elem['elements'] += [
    {'name': 'a_self', 'type': 'collision', 'components': {
        'Collision': {'members': ['fur_a'], 'method': 'edge_edge', 'pairs': 'self'}, 'CollisionResponse': dict(r)}},
    {'name': 'a_b', 'type': 'collision', 'components': {
        'Collision': {'members': ['fur_a', 'fur_b'], 'method': 'edge_edge', 'pairs': 'between'},
        'CollisionResponse': dict(r)}}]
dump(elem, 'two_elem')
alone = copy.deepcopy(elem); alone['elements'].pop()  # no a_b
dump(alone, 'two_alone')
damped = copy.deepcopy(elem)
for e in damped['elements'][3:]: e['components']['CollisionResponse']['damping'] = 0.05
dump(damped, 'two_damped')
# 3. a 17 x 17 panel dropped on a ball folds onto itself
n = 17
with open(f'{S}/panel.obj', 'w') as f:
    for j in range(n):
        for i in range(n): f.write(f'v {-0.5 + i / (n - 1):.6f} 0 {-0.5 + j / (n - 1):.6f}\n')
    for j in range(n - 1):
        for i in range(n - 1):
            p = j * n + i + 1; q = p + 1; u = p + n; w = u + 1
            f.write(f'f {p} {u} {w}\nf {p} {w} {q}\n' if (i + j) % 2 == 0 else f'f {p} {u} {q}\nf {q} {u} {w}\n')
cloth = {'name': 'sheet', 'type': 'cloth', 'components': {
    'Mesh': {'file': 'panel.obj'}, 'Transform': {'translate': [0, 0.25, 0], 'scale': 0.3},
    'ClothMaterial': {'density': 500, 'thickness': 1e-3, 'youngs_modulus': 2e5, 'bend_scale': 0.05, 'damping': 0.005},
    'ClothSolver': {'substeps': 8}}}
ball = {'name': 'ball', 'type': 'collider', 'components': {
    'Mesh': {'file': root + '/assets/meshes/sphere.obj'}, 'Transform': {'translate': [0, 0.15, 0], 'scale': 0.05},
    'Collider': {'friction': 0.3}}}
fold = {'shot': {'name': 'fold', 'fps': 24, 'frames': [1, 10]}, 'elements': [cloth, ball]}
c = copy.deepcopy(fold); c['elements'][0]['components']['ClothMaterial']['self_contact'] = True
dump(c, 'fold_short')
c = copy.deepcopy(fold)
c['elements'].append({'name': 'layers', 'type': 'collision', 'components': {
    'Collision': {'members': ['sheet'], 'method': 'vertex_face'}}})
dump(c, 'fold_elem')
c['elements'][-1]['components']['CollisionResponse'] = {'thickness': 0.003}
dump(c, 'fold_thick')
c = copy.deepcopy(fold)  # a collision element for something else: the panel then makes no self contact
c['elements'].append({'name': 'other', 'type': 'hair', 'components': base['elements'][0]['components'] | {}})
c['elements'][-1]['components'].pop('CollisionResponse')
c['elements'][-1]['components']['Transform']['translate'] = [1, 0.2, 0]  # away from the ball
c['elements'].append({'name': 'strands', 'type': 'collision', 'components': {
    'Collision': {'members': ['other'], 'method': 'edge_edge'}}})
c['shot']['frames'] = [1, 8]
dump(c, 'fold_none')
PY

W="$WORK/b"
mkdir -p "$W"
for s in one_short one_elem two_short two_elem two_alone two_damped; do
  check "$s bakes without a warning" bake_quiet "$S/$s.json" "$W/$s"
done
check "hair_small written with a collision element bakes the same numbers as with its CollisionResponse" \
  same_data "$W/one_short" "$W/one_elem" hair_small 8
check "two grooms' masks written as collision elements bake the same numbers" same_data "$W/two_short" "$W/two_elem" two 4
check "their strands touch each other (contacts found)" \
  test "$(sum_key "$W/two_elem/two/bake/progress.jsonl" hair_contacts)" -gt 0
check "without the collision element between them the second groom moves otherwise" \
  differ "$W/two_elem" "$W/two_alone" two 4 /fur_b/position
check "a response with damping bakes without a warning and changes the strands" \
  differ "$W/two_elem" "$W/two_damped" two 4 /fur_a/position

for s in fold_short fold_elem fold_thick fold_none; do
  check "$s bakes without a warning" bake_quiet "$S/$s.json" "$W/$s"
done
check "a panel's self contact written as a vertex_face collision element is its ClothMaterial.self_contact" \
  same_data "$W/fold_short" "$W/fold_elem" fold 10
sc=$(sum_key "$W/fold_elem/fold/bake/progress.jsonl" cloth_self_contacts)
echo "self contacts over the fold: $sc"
check "the folding panel makes self contacts" test "$sc" -gt 0
check "the collision element's thickness applies" differ "$W/fold_elem" "$W/fold_thick" fold 10 /sheet/position
check "a panel no collision element lists makes no self contact" \
  test "$(sum_key "$W/fold_none/fold/bake/progress.jsonl" cloth_self_contacts)" -eq 0

# bad collision elements: exit 2 naming the element, the field and the fix; nothing written
bad() { # NAME PATTERN PYTHON-EDIT
  python3 - "$S/two_elem.json" "$S/bad.json" "$3" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); exec(sys.argv[3]); json.dump(s, open(sys.argv[2], 'w'))
PY
  rm -rf "$W/bad"
  expect_exit "$1" 2 "$2" "$BIN/bake" "$S/bad.json" --out "$W/bad"
  check "$1: nothing written" test ! -e "$W/bad/two/bake/frame.0001.h5"
}
bad "a member that is no element" "a_b.Collision.members\[1\] = 'fur_c': no hair or cloth element has this name; did you mean 'fur_a'\?" \
  "s['elements'][4]['components']['Collision']['members'][1] = 'fur_c'"
bad "a collider as a member" "a_b.Collision.members\[1\] = 'head' is a collider element; members are hair or cloth" \
  "s['elements'][4]['components']['Collision']['members'][1] = 'head'"
bad "a pair in two collision elements" "a_self and a_b both meet fur_a with itself .*leave it in one of them" \
  "s['elements'][4]['components']['Collision']['pairs'] = 'all'"
bad "the hair's shorthand beside collision elements" "fur_b.CollisionGroup is the shorthand of collision elements.*Remove fur_b.CollisionGroup" \
  "s['elements'][1]['components']['CollisionGroup'] = {'group': 1}"
bad "a negative damping" "a_b.CollisionResponse.damping = -1 is out of range \[0, 10\] s" \
  "s['elements'][4]['components']['CollisionResponse']['damping'] = -1"
