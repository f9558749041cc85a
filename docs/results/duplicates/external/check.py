"""Copies of every CAPOD model made by simplifiers the eval does not run, checked against a
running service that holds the originals: what a library's users upload.

Each model is loaded with trimesh (vertices merged), simplified by pyfqmr and by pyvista's
fast_simplification (both Forstmann's fast quadric simplification) to 40-60 % of its
triangles, turned by a random rotation, scaled by 25.4 or 0.1, moved, and written as binary
STL or GLB. Each copy goes to `POST /v1/duplicates/check`; the row says the evidence it was
found with beside its source (or MISSED) and any other model it was linked to.

    pip install pyfqmr==0.3.0 fast-simplification==0.2.0 trimesh==4.*
    salient serve --addr 127.0.0.1:18080 --data /tmp/capod-store &
    salient ingest ../shared/data/capod --class-from-folder --server http://127.0.0.1:18080
    python3 docs/results/duplicates/external/check.py ../shared/data/capod \
        http://127.0.0.1:18080 /tmp/external > docs/results/duplicates/external/results.tsv

Deterministic (seeded); `salient ingest --class-from-folder` gives CAPOD's models the ids
`CLASS-MODEL` that the rows compare with.
"""
import json
import os
import sys
import time
import urllib.error
import urllib.request

import fast_simplification
import numpy as np
import pyfqmr
import trimesh


def copies(root, out, rng):
    """(class, model, simplifier, path) of each copy, written into `out`."""
    os.makedirs(out, exist_ok=True)
    for c in sorted(d for d in os.listdir(root) if os.path.isdir(os.path.join(root, d))):
        for f in sorted(f for f in os.listdir(os.path.join(root, c)) if f.endswith('.obj')):
            mesh = trimesh.load(os.path.join(root, c, f), process=True, force='mesh')
            v = np.asarray(mesh.vertices, dtype=np.float64)
            t = np.asarray(mesh.faces, dtype=np.int64)
            target = int(len(t) * rng.uniform(0.4, 0.6))
            s = pyfqmr.Simplify()
            s.setMesh(v, t)
            s.simplify_mesh(target_count=target, aggressiveness=7, preserve_border=False,
                            verbose=False)
            pv, pt, _ = s.getMesh()
            fv, ft = fast_simplification.simplify(
                v.astype(np.float32), t.astype(np.int32),
                target_reduction=1 - target / len(t))
            for name, (cv, ct) in [('pyfqmr', (pv, pt)), ('fast_simplification', (fv, ft))]:
                q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
                if np.linalg.det(q) < 0:
                    q[:, 0] *= -1
                scale = [25.4, 0.1][rng.integers(2)]
                moved = (np.asarray(cv, dtype=np.float64) @ q.T) * scale + rng.normal(size=3) * 10
                ext = ['stl', 'glb'][rng.integers(2)]
                path = os.path.join(out, f'{c}_{f[:-4]}_{name}.{ext}')
                trimesh.Trimesh(moved, ct, process=False).export(path)
                yield c, f[:-4], name, path


def check(server, path):
    kind = 'model/stl' if path.endswith('.stl') else 'model/gltf-binary'
    request = urllib.request.Request(
        server.rstrip('/') + '/v1/duplicates/check', data=open(path, 'rb').read(),
        headers={'Content-Type': kind}, method='POST')
    try:
        return json.load(urllib.request.urlopen(request, timeout=600)), ''
    except urllib.error.HTTPError as e:
        return {}, f'HTTP {e.code}'


def main(root, server, out):
    rng = np.random.default_rng(20261207)
    print('class\tmodel\tsimplifier\tevidence\tother models linked\tseconds\terror')
    for c, m, name, path in copies(root, out, rng):
        clock = time.time()
        response, error = check(server, path)
        seconds = time.time() - clock
        matches = response.get('matches', [])
        own = [x['evidence'] for x in matches if x['id'] == f'{c}-{m}']
        others = ','.join(f"{x['id']}:{x['evidence']}" for x in matches if x['id'] != f'{c}-{m}')
        print(c, m, name, own[0] if own else 'MISSED', others, f'{seconds:.1f}', error,
              sep='\t', flush=True)


if __name__ == '__main__':
    main(*sys.argv[1:4])
