#!/usr/bin/python3
"""Independent readers for fracnav's exports (test_export.c): nothing here shares code with the
writers in src/core/io/export.c. Each command prints one JSON object.

  export_read.py tfm FILE X,Y,Z ...   the ITK transform (parsed here) applied to each point
  export_read.py nifti FILE           shape, RAS affine and label counts (nibabel)
  export_read.py segnrrd FILE [NIFTI] Slicer segment fields, label counts, extents checked (a NRRD
                                      parser here + numpy); with NIFTI: whether the voxels equal it
  export_read.py stl FILE             triangles, whether closed and consistently wound (every
                                      directed edge once, its reverse once), volume, bounds
"""
import gzip
import json
import struct
import sys


def tfm(path, points):
    fields = {}
    with open(path) as f:
        lines = [l.rstrip("\n") for l in f]
    if lines[0] != "#Insight Transform File V1.0":
        raise SystemExit("not an ITK transform file")
    for l in lines[1:]:
        if ":" in l and not l.startswith("#"):
            k, v = l.split(":", 1)
            fields[k.strip()] = v.split()
    if fields["Transform"] != ["AffineTransform_double_3_3"]:
        raise SystemExit("unexpected transform %s" % fields["Transform"])
    p = [float(x) for x in fields["Parameters"]]
    c = [float(x) for x in fields["FixedParameters"]]
    a = [p[0:3], p[3:6], p[6:9]]
    t = p[9:12]
    out = []
    for s in points:
        x = [float(v) for v in s.split(",")]
        # ITK's MatrixOffsetTransformBase: y = A (x - c) + c + T
        out.append([sum(a[r][k] * (x[k] - c[k]) for k in range(3)) + c[r] + t[r] for r in range(3)])
    return {"points": out, "parameters": len(p), "fixed_parameters": len(c)}


def nifti(path):
    import nibabel as nib
    import numpy as np
    img = nib.load(path)
    d = np.asarray(img.dataobj)
    labels, counts = np.unique(d, return_counts=True)
    return {"shape": list(d.shape), "dtype": str(d.dtype), "affine": img.affine.tolist(),
            "sform_code": int(img.header["sform_code"]),
            "counts": {str(int(l)): int(n) for l, n in zip(labels, counts) if l != 0}}


def read_nrrd(path):
    import numpy as np
    with open(path, "rb") as f:
        raw = f.read()
    head, _, data = raw.partition(b"\n\n")
    lines = head.decode("latin-1").split("\n")
    if not lines[0].startswith("NRRD000"):
        raise SystemExit("not a NRRD")
    fields, kv = {}, {}
    for l in lines[1:]:
        if l.startswith("#"):
            continue
        if ":=" in l:
            k, v = l.split(":=", 1)
            kv[k] = v
        elif ": " in l:
            k, v = l.split(": ", 1)
            fields[k] = v
    sizes = [int(x) for x in fields["sizes"].split()]
    types = {"unsigned short": "<u2", "short": "<i2", "unsigned char": "u1", "int": "<i4"}
    if fields["encoding"] == "gzip":
        data = gzip.decompress(data)
    arr = np.frombuffer(data, dtype=types[fields["type"]]).reshape(sizes[::-1]).transpose(2, 1, 0)
    return fields, kv, arr


def segnrrd(path, nifti_path=None):
    import numpy as np
    fields, kv, arr = read_nrrd(path)
    segs = []
    n = 0
    while "Segment%d_ID" % n in kv:
        s = {k: kv["Segment%d_%s" % (n, k)] for k in ("ID", "Name", "Color", "LabelValue", "Layer", "Extent")}
        lv = int(s["LabelValue"])
        idx = np.argwhere(arr == lv)
        e = [int(x) for x in s["Extent"].split()]
        s["voxels"] = int(len(idx))
        s["extent_holds_voxels"] = bool(len(idx) == 0 or all(
            e[2 * a] <= idx[:, a].min() and idx[:, a].max() <= e[2 * a + 1] for a in range(3)))
        segs.append(s)
        n += 1
    out = {"space": fields.get("space"), "space_directions": fields.get("space directions"),
           "space_origin": fields.get("space origin"), "shape": list(arr.shape), "segments": segs,
           "master": kv.get("Segmentation_MasterRepresentation")}
    if nifti_path:
        import nibabel as nib
        out["equals_nifti"] = bool(np.array_equal(np.asarray(nib.load(nifti_path).dataobj), arr))
    return out


def stl(path):
    with open(path, "rb") as f:
        raw = f.read()
    (n,) = struct.unpack_from("<I", raw, 80)
    if len(raw) != 84 + 50 * n:
        raise SystemExit("size %d does not match %d triangles" % (len(raw), n))
    directed = {}
    vol = 0.0
    lo = [float("inf")] * 3
    hi = [-float("inf")] * 3
    for t in range(n):
        v = struct.unpack_from("<9f", raw, 84 + 50 * t + 12)
        p = [tuple(v[0:3]), tuple(v[3:6]), tuple(v[6:9])]
        for q in p:
            for a in range(3):
                lo[a] = min(lo[a], q[a])
                hi[a] = max(hi[a], q[a])
        for e in range(3):
            key = (p[e], p[(e + 1) % 3])
            directed[key] = directed.get(key, 0) + 1
        a, b, c = p
        vol += (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
                a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0
    closed = all(k == 1 and directed.get((e[1], e[0])) == 1 for e, k in directed.items())
    header = raw[:80].split(b"\0")[0].decode("latin-1")
    return {"triangles": n, "closed": closed, "volume_mm3": vol, "lo": lo, "hi": hi, "header": header}


def main():
    cmd, path = sys.argv[1], sys.argv[2]
    if cmd == "tfm":
        r = tfm(path, sys.argv[3:])
    elif cmd == "nifti":
        r = nifti(path)
    elif cmd == "segnrrd":
        r = segnrrd(path, sys.argv[3] if len(sys.argv) > 3 else None)
    elif cmd == "stl":
        r = stl(path)
    else:
        raise SystemExit("unknown command " + cmd)
    print(json.dumps(r))


if __name__ == "__main__":
    main()
