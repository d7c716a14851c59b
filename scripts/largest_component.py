"""The largest connected component (by triangle count) of a binary PLY mesh as psneus writes it
(float xyz vertices, uchar-count int faces): a diagnostic of floaters. Not run by CI; needs numpy.

usage: python3 scripts/largest_component.py IN.ply OUT.ply
then:  cargo xtask eval --mesh OUT.ply --data SCENE   (compare with the whole mesh)
"""
import sys

import numpy as np

src, dst = sys.argv[1], sys.argv[2]
data = open(src, 'rb').read()
end = data.index(b'end_header\n') + len(b'end_header\n')
header = data[:end].decode()
nv = int(header.split('element vertex ')[1].split()[0]); nf = int(header.split('element face ')[1].split()[0])
v = np.frombuffer(data, dtype='<f4', count=3 * nv, offset=end).reshape(nv, 3)
rec = np.dtype([('n', 'u1'), ('i', '<i4', 3)])
f = np.frombuffer(data, dtype=rec, count=nf, offset=end + 12 * nv)['i']
parent = list(range(nv))
def find(a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]; a = parent[a]
    return a
for t in f.tolist():
    ra = find(t[0])
    for x in t[1:]:
        rb = find(x)
        if ra != rb: parent[rb] = ra
root = np.array([find(a) for a in range(nv)])
tri_root = root[f[:, 0]]
labels, counts = np.unique(tri_root, return_counts=True)
keep = labels[np.argmax(counts)]
ff = f[tri_root == keep]
used = np.unique(ff)
remap = -np.ones(nv, dtype=np.int64); remap[used] = np.arange(len(used))
vv = v[used]; ff = remap[ff]
out = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n" % (len(vv), len(ff))).encode()
frec = np.zeros(len(ff), dtype=rec); frec['n'] = 3; frec['i'] = ff
open(dst, 'wb').write(out + vv.astype('<f4').tobytes() + frec.tobytes())
print(len(labels), 'components; kept', counts.max(), 'of', nf, 'triangles')
