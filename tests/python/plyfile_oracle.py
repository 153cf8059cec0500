"""A PLY reader written for the tests, independent of slshadow's (an oracle): the vertex element of
an ascii or binary little-endian file as a dict property name -> numpy array."""

import numpy as np

_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
          "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
          "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "float32": "<f4",
          "float64": "<f8"}


def read_vertices(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    fmt = None
    count = 0
    props = []
    in_vertex = False
    for line in header:
        words = line.split()
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            in_vertex = words[1] == "vertex"
            if in_vertex:
                count = int(words[2])
        elif words[0] == "property" and in_vertex:
            assert words[1] != "list", "vertex list properties are not expected"
            props.append((words[2], _TYPES[words[1]]))
    dtype = np.dtype([(name, t) for name, t in props])
    if fmt == "binary_little_endian":
        table = np.frombuffer(data, dtype=dtype, count=count, offset=end)
    else:
        assert fmt == "ascii", fmt
        rows = data[end:].decode("ascii").split("\n")[:count]
        table = np.array([tuple(r.split()) for r in rows], dtype=[(n, "U40") for n, _ in props])
        table = table.astype(dtype)
    return {name: np.array(table[name]) for name, _ in props}
