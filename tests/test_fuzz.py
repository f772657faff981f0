"""Hostile input, measured: a seeded mutator corrupts small valid EXRs (header, offset table,
pixel data; truncation, zeroed ranges, inserted bytes, hostile header fields) and feeds them
to `fgen info --scan`, `fgen convert` and `fgen interpolate`.

Every case must end in exit 0 or 1: never a crash (signal), a hang, a Python traceback or
fgen's "internal error" path. Exit 1 must come with one `Error:` line on stderr naming the
corrupt file (other stderr lines may only be warnings or notes). Exit 0 is allowed only when
the mutated file still reads completely with OpenImageIO (every part, every channel decodes
without an error): a flip in the pixels of an uncompressed file just changes a value, a flip
in an unused attribute changes nothing. convert and interpolate run with --resume into a
folder that already holds a valid output: it must be byte-identical afterwards, whatever
happened, and no temporary file may be left.

Cases run in batches: one driver process per command (`python -c DRIVER`) calls
`fgcli.cli.main` once per case and prints one JSON line per case; a segfault or abort kills
the driver and the test names the case it was on, a hang trips the driver's per-case
watchdog (faulthandler). A few cases also run through real `python -m fgcli` subprocesses
for the exact stderr and exit code. The fast test tries ~170 cases in all (every hostile
header on info, a share of them on convert and interpolate); the slow one (`-m slow`) 1000+
per command over eight compressions, tiled, multi-part and data-window files.
"""
from __future__ import annotations

import json
import os
import random
import shutil
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from fgcli.io import exr

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FGEN = [sys.executable, "-m", "fgcli"]
SCENE = os.path.join(ROOT, "sample_data", "scenes", "orbit.toml")
FRAMES = ["orbit.0000.exr", "orbit.0001.exr", "orbit.0002.exr"]
CASE_TIMEOUT = 60  # seconds before the driver's watchdog ends a hung case
CASE_SLOW = 10  # seconds one case may take (they take well under one)


# -- EXR structure: where the header, the offset table and the chunks are ------------------

def header_end(data: bytes) -> int:
    """Offset just past the header(s) (multi-part: past the empty header ending the list)."""
    (version,) = struct.unpack_from("<I", data, 4)
    multipart = bool(version & 0x1000)
    pos = 8
    while True:
        while True:
            end = data.index(b"\0", pos)
            if end == pos:
                pos += 1
                break
            tend = data.index(b"\0", end + 1)
            (n,) = struct.unpack_from("<i", data, tend + 1)
            pos = tend + 5 + n
        if not multipart or data[pos:pos + 1] == b"\0":
            return pos + (1 if multipart else 0)


def regions(data: bytes) -> tuple[int, int]:
    """(end of the header, end of the offset table) of a valid file."""
    he = header_end(data)
    (first,) = struct.unpack_from("<Q", data, he)
    return he, first


def attributes(data: bytes) -> list[tuple[str, str, int, int]]:
    """(name, type, value offset, value size) of the first header's attributes."""
    out, pos = [], 8
    while True:
        end = data.index(b"\0", pos)
        if end == pos:
            return out
        tend = data.index(b"\0", end + 1)
        (n,) = struct.unpack_from("<i", data, tend + 1)
        out.append((data[pos:end].decode(), data[end + 1:tend].decode(), tend + 5, n))
        pos = tend + 5 + n


def with_header(data: bytes, attrs: list[tuple[str, str, bytes]]) -> bytes:
    """`data` (single part) with its header replaced by `attrs`, chunk offsets shifted."""
    he, first = regions(data)
    n = (first - he) // 8
    offsets = struct.unpack_from(f"<{n}Q", data, he)
    h = bytearray(data[:8])
    for name, typ, value in attrs:
        h += name.encode("utf-8", "surrogateescape") + b"\0" + typ.encode() + b"\0"
        h += struct.pack("<i", len(value)) + value
    h += b"\0"
    d = len(h) - he
    return bytes(h) + struct.pack(f"<{n}Q", *[o + d for o in offsets]) + data[he + 8 * n:]


def edit_header(data: bytes, **changes) -> bytes:
    """Replace attribute values (bytes), add attributes ((type, bytes)) or drop them (None)."""
    out = []
    for name, typ, p, n in attributes(data):
        if name in changes:
            new = changes.pop(name)
            if new is None:
                continue
            typ, value = new if isinstance(new, tuple) else (typ, new)
            out.append((name, typ, value))
        else:
            out.append((name, typ, data[p:p + n]))
    out += [(k, t, v) for k, (t, v) in changes.items()]
    return with_header(data, out)


def _box(*v) -> bytes:
    return struct.pack("<4i", *v)


def _channels(data: bytes) -> list[tuple[str, int, int, int]]:
    value = next(data[p:p + n] for name, _, p, n in attributes(data) if name == "channels")
    out, p = [], 0
    while value[p]:
        e = value.index(b"\0", p)
        pt, _, xs, ys = struct.unpack_from("<iB3xii", value, e + 1)
        out.append((value[p:e].decode("utf-8", "surrogateescape"), pt, xs, ys))
        p = e + 17
    return out


def _chlist(chs) -> bytes:
    out = b""
    for name, pt, xs, ys in chs:
        out += name.encode("utf-8", "surrogateescape") + b"\0" + struct.pack("<iB3xii", pt, 0,
                                                                           xs, ys)
    return out + b"\0"


def _set_u64(data: bytes, at: int, value: int) -> bytes:
    b = bytearray(data)
    struct.pack_into("<Q", b, at, value)
    return bytes(b)


# Hostile headers and tables, each a function of the valid file's bytes. The comment says
# what it probes; all are single-part scanline edits of a frame written by `fgen synth`.
HOSTILE = {
    # absurd sizes: OpenImageIO's limits, or fgen's memory rule
    "data_window_1e9": lambda b: edit_header(b, dataWindow=_box(0, 0, 10**9, 10**9)),
    "windows_1e9": lambda b: edit_header(b, dataWindow=_box(0, 0, 10**9, 10**9),
                                         displayWindow=_box(0, 0, 10**9, 10**9)),
    "display_4TiB": lambda b: edit_header(b, displayWindow=_box(0, 0, 2**20 - 1, 2**20 - 1)),
    "data_window_int_limits": lambda b: edit_header(
        b, dataWindow=_box(-2**31, -2**31, 2**31 - 1, 2**31 - 1)),
    "data_window_inverted": lambda b: edit_header(b, dataWindow=_box(31, 23, 0, 0)),
    "data_window_tall": lambda b: edit_header(b, dataWindow=_box(0, 0, 31, 99999)),
    "data_window_1e6_rows": lambda b: edit_header(b, dataWindow=_box(0, 0, 31, 10**6 - 1),
                                                  displayWindow=_box(0, 0, 31, 10**6 - 1)),
    "data_window_5000": lambda b: edit_header(b, dataWindow=_box(0, 0, 4999, 4999),
                                              displayWindow=_box(0, 0, 4999, 4999)),
    "channels_5000": lambda b: edit_header(
        b, channels=_chlist([(f"c{i:05d}", 1, 1, 1) for i in range(5000)])),
    "channels_none": lambda b: edit_header(b, channels=b"\0"),
    "channels_subsampled": lambda b: edit_header(
        b, channels=_chlist([(n, t, 2, 2) for n, t, _, _ in _channels(b)])),
    "channels_bad_type": lambda b: edit_header(
        b, channels=_chlist([(n, 7, x, y) for n, _, x, y in _channels(b)])),
    "channels_float_claimed": lambda b: edit_header(
        b, channels=_chlist([(n, 2, x, y) for n, _, x, y in _channels(b)])),
    "channel_name_not_utf8": lambda b: edit_header(
        b, channels=_chlist([("\udcff" + n if n == "R" else n, t, x, y)
                             for n, t, x, y in _channels(b)])),
    "tiles_on_scanline": lambda b: edit_header(
        b, tiles=("tiledesc", struct.pack("<iiB", 1, 1, 0))),
    "tiled_flag_no_tiles": lambda b: b[:5] + bytes([b[5] | 0x02]) + b[6:],
    "deep_flag": lambda b: b[:5] + bytes([b[5] | 0x08]) + b[6:],
    "multipart_flag": lambda b: b[:5] + bytes([b[5] | 0x10]) + b[6:],
    "compression_200": lambda b: edit_header(b, compression=bytes([200])),
    "compression_wrong": lambda b: edit_header(b, compression=bytes([4])),
    "chunk_count_huge": lambda b: edit_header(
        b, chunkCount=("int", struct.pack("<i", 2**31 - 1))),
    "string_size_huge": lambda b: b.replace(b"string\0\x05\x00\x00\x00",
                                            b"string\0\xff\xff\xff\x7f", 1),
    "string_not_utf8": lambda b: edit_header(b, **{"fgen:synth_role": b"\xff\xfe\x80"}),
    "attribute_name_unterminated": lambda b: (lambda i: b[:i] + b"\x80" + b[i + 1:])(
        b.index(b"fgen:mv_space\0") + len("fgen:mv_space")),
    "attribute_name_not_utf8": lambda b: edit_header(
        b, **{"fgen:\udcff": ("string", b"x")}),
    "attributes_20000": lambda b: edit_header(
        b, **{f"a{i}": ("int", b"\0\0\0\0") for i in range(20000)}),
    "camera_json_broken": lambda b: edit_header(b, **{"fgen:projection": b"[[1, 2], [3"}),
    "pixel_aspect_nan": lambda b: edit_header(
        b, pixelAspectRatio=struct.pack("<f", float("nan"))),
    # offset table and chunks
    "offset_past_end": lambda b: _set_u64(b, regions(b)[0] + 8, len(b) + 1000),
    "offset_2e63": lambda b: _set_u64(b, regions(b)[0], 2**63),
    "offsets_all_past_end": lambda b: _set_u64(_set_u64(b, regions(b)[0], len(b) * 3),
                                               regions(b)[0] + 8, len(b) * 4),
    "offset_into_header": lambda b: _set_u64(b, regions(b)[0] + 8, 8),
    "chunk_size_huge": lambda b: (lambda o: b[:o + 4] + struct.pack("<i", 2**31 - 1)
                                  + b[o + 8:])(regions(b)[1]),
    "chunk_size_negative": lambda b: (lambda o: b[:o + 4] + struct.pack("<i", -1)
                                      + b[o + 8:])(regions(b)[1]),
    "chunk_y_wrong": lambda b: (lambda o: b[:o] + struct.pack("<i", 12345678)
                                + b[o + 4:])(regions(b)[1]),
    "header_only": lambda b: b[:regions(b)[0]],
    "header_and_table_only": lambda b: b[:regions(b)[1]],
    "magic_only": lambda b: b[:4],
    "empty": lambda b: b"",
    "not_exr": lambda b: b"P6\n32 24\n255\n" + bytes(32 * 24 * 3),
}

INTERESTING = [0, 1, -1, 2, 7, 8, 15, 16, 17, 31, 32, 255, 256, 0x7FFF, 0x8000, 0xFFFF,
               0x7FFFFFFF, -0x80000000, 0x40000000, 1048576, 1048577, 23, 24]


def mutate(data: bytes, rng: random.Random, kind: str) -> bytes:
    """One seeded mutation of a valid single- or multi-part file."""
    b = bytearray(data)
    he, te = regions(data)
    n = len(b)
    spans = {"header": (8, he), "magic": (0, 8), "table": (he, te), "data": (te, n)}
    if kind in spans:
        lo, hi = spans[kind]
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(lo, hi)
            if rng.random() < 0.5:
                b[i] ^= 1 << rng.randrange(8)
            else:
                b[i] = rng.randrange(256)
        return bytes(b)
    if kind == "truncate":
        return bytes(b[:rng.randrange(0, n)])
    if kind == "zero":
        i = rng.randrange(0, n)
        size = rng.choice([1, 4, 8, 16, 64, 256])
        b[i:i + size] = bytes(len(b[i:i + size]))
        return bytes(b)
    if kind == "insert":
        i = rng.randrange(0, n)
        return bytes(b[:i] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 32)))
                     + b[i:])
    if kind == "field":  # an int32 of an attribute value, a table entry or a chunk header
        r = rng.random()
        if r < 0.5:
            _, _, p, size = rng.choice([a for a in attributes(data) if a[3] > 0])
            if size >= 4:
                struct.pack_into("<i", b, p + 4 * rng.randrange(size // 4),
                                 rng.choice(INTERESTING))
            else:
                b[p + rng.randrange(size)] = rng.choice([0, 1, 2, 3, 4, 8, 9, 10, 15, 128, 255])
        elif r < 0.75:
            entries = max(1, (te - he) // 8)
            struct.pack_into("<Q", b, he + 8 * rng.randrange(entries),
                             rng.choice([0, 8, he, n - 1, n, n + 8, 2**32, 2**63, 2**64 - 1]))
        else:
            entries = max(1, (te - he) // 8)
            (o,) = struct.unpack_from("<Q", data, he + 8 * rng.randrange(entries))
            f = rng.randrange(5)
            if o + 4 * f + 4 <= n:
                struct.pack_into("<i", b, o + 4 * f, rng.choice(INTERESTING))
        return bytes(b)
    raise ValueError(kind)


KINDS = ["header", "table", "data", "truncate", "zero", "insert", "field", "header",
         "data", "magic"]


# -- sources -----------------------------------------------------------------------------

def _synth(folder) -> None:
    r = subprocess.run(FGEN + ["synth", SCENE, str(folder), "--size", "32x24", "--frames", "3",
                               "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr


def _variant(src, dst, name: str) -> None:
    """The sequence in `src` rewritten as `name`: a compression, optionally '-tiledN' (N x N
    tiles), '-multipart' (color in one part, the rest in another) or '-dw' (a data window
    smaller than the display window)."""
    comp, _, shape = name.partition("-")
    os.makedirs(dst)
    for fn in os.listdir(src):
        if not fn.endswith(".exr"):
            shutil.copy(os.path.join(src, fn), os.path.join(dst, fn))
            continue
        h = exr.read_header(os.path.join(src, fn))
        p = h.parts[0]
        ch = exr.read_channels(h.path, [(0, c) for c in p.channels], h)
        chans = {c: ch[(0, c)] for c in p.channels}
        types = {c: ("float" if f == "float" else "half") for c, f in zip(p.channels, p.formats)}
        out = os.path.join(dst, fn)
        if shape == "multipart":
            rgba = [c for c in p.channels if c in "RGBA"]
            exr.write_parts(out, [
                dict(channels={c: chans[c] for c in rgba}, types=types, name="rgba",
                     attributes=h.attributes, attribute_types=h.attribute_types),
                dict(channels={c: chans[c] for c in chans if c not in rgba}, types=types,
                     name="aux")], compression=comp)
        elif shape == "dw":
            exr.write_exr(out, {c: a[2:22, 1:30] for c, a in chans.items()}, types,
                          h.attributes, comp, attribute_types=h.attribute_types,
                          data_window=(1, 2, 29, 20), display=(p.width, p.height))
        else:
            tile = int(shape[len("tiled"):]) if shape.startswith("tiled") else None
            exr.write_exr(out, chans, types, h.attributes, comp,
                          attribute_types=h.attribute_types, tile=tile)


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    """name -> folder of a valid 3-frame 32x24 sequence (fgen layout, cameras in headers);
    created on first use."""
    root = tmp_path_factory.mktemp("fuzz-src")
    made: dict[str, str] = {}

    def get(name: str) -> str:
        if name not in made:
            folder = str(root / name)
            if name == "zip":
                _synth(folder)
            else:
                _variant(get("zip"), folder, name)
            made[name] = folder
        return made[name]

    return get


# -- the batch driver -------------------------------------------------------------------

DRIVER = r'''
import contextlib, faulthandler, io, json, os, shutil, sys, time
import numpy as np
import OpenImageIO as oiio
cases = json.load(open(sys.argv[1]))
timeout = float(sys.argv[2])
from fgcli import cli

def reads_completely(path):
    """True when OpenImageIO decodes every part and channel of `path` without an error."""
    inp = oiio.ImageInput.open(path)
    if inp is None:
        try:
            oiio.geterror()
        except Exception:
            pass
        return False
    def error():
        try:
            return inp.geterror()
        except Exception:
            return "undecodable error message"

    ok, k = True, 0
    try:
        while inp.seek_subimage(k, 0):
            s = inp.spec()
            d = inp.read_image(k, 0, 0, s.nchannels, "float")
            if not isinstance(d, np.ndarray) or d.size == 0 or error():
                ok = False
            k += 1
        error()  # the failed seek past the last part
    finally:
        inp.close()
    return ok and k > 0

def first_exr(folder):
    return sorted(f for f in os.listdir(folder) if f.endswith(".exr"))[0]

for c in cases:
    print(json.dumps({"start": c["id"]}), flush=True)
    if "seed" in c:  # an output folder that already holds the reference run's first output
        ref_dir, out_dir = c["seed"]
        os.makedirs(out_dir)
        shutil.copy(os.path.join(ref_dir, first_exr(ref_dir)), out_dir)
    shutil.copy(c["mutated"], c["target"])
    out, err = io.StringIO(), io.StringIO()
    faulthandler.dump_traceback_later(timeout, exit=True)
    t0 = time.perf_counter()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            cli.main(c["argv"])
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else repr(e.code)
        except BaseException as e:
            code = "escaped: %s: %s" % (type(e).__name__, e)
    sec = time.perf_counter() - t0
    faulthandler.cancel_dump_traceback_later()
    valid = reads_completely(c["target"]) if code == 0 else None
    shutil.copy(c["original"], c["target"])
    print(json.dumps({"id": c["id"], "code": code, "stderr": err.getvalue(),
                      "valid": valid, "sec": round(sec, 3)}), flush=True)
print(json.dumps({"done": len(cases)}), flush=True)
'''


def make_cases(cmd: str, src: str, work: str, count: int, seed: int,
               hostile: list[str] = ()) -> list[dict]:
    """`count` seeded random cases (and the named hostile ones) for one command over one
    source sequence. Each case: a mutated copy of one frame and the argv. convert and
    interpolate start with a clean reference run; every later case runs with --resume into a
    folder that already holds the reference run's first output."""
    seq = os.path.join(work, "in")
    shutil.copytree(src, seq)
    os.makedirs(os.path.join(work, "cases"))
    originals = {}
    for fn in FRAMES:
        originals[fn] = os.path.join(work, "cases", "orig-" + fn)
        shutil.copy(os.path.join(seq, fn), originals[fn])
    flags = ["--no-progress"] if cmd == "interpolate" else []
    ref = os.path.join(work, "ref")
    cases = []
    if cmd != "info":
        cases.append({"id": f"{cmd}:{os.path.basename(src)}:reference", "kind": "reference",
                      "mutated": originals[FRAMES[1]], "target": os.path.join(seq, FRAMES[1]),
                      "original": originals[FRAMES[1]], "argv": [cmd, seq, ref] + flags})
    rng_all = random.Random(seed)
    plan = [("hostile", h) for h in hostile] + [("random", None)] * count
    for i, (what, name) in enumerate(plan):
        rng = random.Random(rng_all.getrandbits(32))
        # info reads every frame; convert/interpolate --resume skip frame 0's work, so the
        # corrupt frame is one the run must read
        frame = FRAMES[i % 3] if cmd == "info" else FRAMES[1 + i % 2]
        with open(originals[frame], "rb") as fh:
            data = fh.read()
        if what == "hostile":
            kind, mutated = name, HOSTILE[name](data)
        else:
            kind = KINDS[rng.randrange(len(KINDS))]
            mutated = mutate(data, rng, kind)
        path = os.path.join(work, "cases", f"{i:04d}.bin")
        with open(path, "wb") as fh:
            fh.write(mutated)
        case = {"id": f"{cmd}:{os.path.basename(src)}:{i}:{kind}", "kind": kind,
                "mutated": path, "target": os.path.join(seq, frame),
                "original": originals[frame]}
        if cmd == "info":
            case["argv"] = ["info", seq, "--scan"]
        else:
            out = os.path.join(work, "out", f"{i:04d}")
            case["argv"] = [cmd, seq, out, "--resume"] + flags
            case["seed"] = [ref, out]
        cases.append(case)
    return cases


def start_batch(cases: list[dict], work: str) -> subprocess.Popen:
    path = os.path.join(work, "cases.json")
    with open(path, "w") as fh:
        json.dump(cases, fh)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-c", DRIVER, path, str(CASE_TIMEOUT)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=work)


def check_batch(proc: subprocess.Popen, cases: list[dict], timeout: float) -> dict:
    """Wait for a driver and check every case; returns counts {tried, exit0, exit1, ...}."""
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        stdout, stderr = proc.communicate()
        pytest.fail(f"driver hung (no result within {timeout} s); last lines: "
                    f"{stdout.splitlines()[-2:]}")
    by_id = {c["id"]: c for c in cases}
    results, current = [], None
    for line in stdout.splitlines():
        if not line.startswith("{"):
            continue
        r = json.loads(line)
        if "start" in r:
            current = r["start"]
        elif "id" in r:
            results.append(r)
            current = None
    if current is not None or proc.returncode != 0:
        c = by_id.get(current, {})
        pytest.fail(f"driver died (exit {proc.returncode}: a crash or a hang) on case "
                    f"{current} (mutated file {c.get('mutated')}); stderr: {stderr[-2000:]}")
    assert len(results) == len(cases)
    # OpenImageIO prints pending (never fetched) error messages at exit: there must be none
    assert not stderr.strip(), stderr[-2000:]
    counts = {"tried": sum(c["kind"] != "reference" for c in cases), "exit0": 0, "exit1": 0}
    failures = []
    for r in results:
        c = by_id[r["id"]]
        err = r["stderr"]
        lines = [ln for ln in err.splitlines() if ln.strip()]
        problem = None
        if r["code"] not in (0, 1):
            problem = f"exit {r['code']!r}"
        elif "Traceback" in err or "internal error" in err:
            problem = "traceback or internal error"
        elif r["code"] == 1:
            if not lines or not lines[-1].startswith("Error: "):
                problem = "exit 1 without an Error line"
            elif c["target"] not in lines[-1]:
                problem = "the error does not name the corrupt file"
            elif any(not ln.startswith(("warning:", "note:")) for ln in lines[:-1]):
                problem = "more than one line besides warnings"
        elif not r["valid"]:
            problem = "exit 0 although the file does not read completely (garbage accepted)"
        if problem is None and r["sec"] > CASE_SLOW and c["kind"] != "reference":
            # (the reference run is the warm-up: it may compile kernels, for once)
            problem = f"took {r['sec']} s"
        if c["kind"] == "reference" and r["code"] != 0:
            problem = "the clean reference run failed"
        if problem is None and "seed" in c:
            ref, out = c["seed"]
            name = sorted(f for f in os.listdir(ref) if f.endswith(".exr"))[0]
            with open(os.path.join(ref, name), "rb") as fa, \
                    open(os.path.join(out, name), "rb") as fb:
                if fa.read() != fb.read():
                    problem = f"existing output {name} changed"
            if any(f.startswith(".") for f in os.listdir(out)):
                problem = f"temporary file left in {out}: {os.listdir(out)}"
        if problem:
            failures.append(f"{r['id']} ({c['mutated']}): {problem}; stderr: {err[-600:]!r}")
        if r["code"] in (0, 1) and c["kind"] != "reference":
            counts[f"exit{r['code']}"] += 1
    assert not failures, f"{len(failures)} of {len(results)} cases failed:\n" + \
        "\n".join(failures[:20])
    return counts


# hostile headers that take another path in convert and interpolate than in info (text
# carried into the outputs, cameras, memory and size rules at read time)
HOSTILE_WRITING = ["string_not_utf8", "attribute_name_not_utf8", "channel_name_not_utf8",
                   "camera_json_broken", "attribute_name_unterminated", "display_4TiB",
                   "attributes_20000", "data_window_tall", "offset_past_end",
                   "chunk_size_huge", "header_only"]


def run_fuzz(tmp_path, sources, plan: dict[str, list[tuple[str, int]]], seed: int,
             hostile: dict[str, list[str]], timeout: float) -> dict:
    """plan: command -> [(source name, random cases)]; hostile: command -> names of HOSTILE
    cases (run on the first source); runs the three commands' drivers at once (one process
    each) and returns {command: counts}."""
    procs = {}
    for cmd, items in plan.items():
        cases = []
        for k, (src, count) in enumerate(items):
            work = str(tmp_path / cmd / src)
            os.makedirs(os.path.dirname(work), exist_ok=True)
            names = hostile.get(cmd, []) if k == 0 else []
            cases += make_cases(cmd, sources(src), work, count, seed + 7919 * k, names)
        procs[cmd] = (start_batch(cases, str(tmp_path / cmd)), cases)
    counts = {}
    for cmd, (proc, cases) in procs.items():
        counts[cmd] = check_batch(proc, cases, timeout)
    print("\nfuzz cases per command:", json.dumps(counts))
    return counts


# -- tests ---------------------------------------------------------------------------------

def test_mutator_is_reproducible(sources):
    with open(os.path.join(sources("zip"), FRAMES[1]), "rb") as fh:
        data = fh.read()
    for kind in set(KINDS):
        a = mutate(data, random.Random(5), kind)
        assert a == mutate(data, random.Random(5), kind)
    he, te = regions(data)
    assert 8 < he < te < len(data)
    assert with_header(data, [(n, t, data[p:p + s]) for n, t, p, s in attributes(data)]) == data


def test_fuzz_fast(tmp_path, sources):
    """Hostile headers plus random mutations for each command (~180 cases, ~10 s)."""
    t0 = time.time()
    counts = run_fuzz(tmp_path, sources, {
        "info": [("zip", 30), ("none", 10), ("zip-multipart", 6)],
        "convert": [("zip", 24), ("none", 8)],
        "interpolate": [("zip", 30), ("none", 10)],
    }, seed=1, hostile={"info": list(HOSTILE), "convert": HOSTILE_WRITING[:6],
                        "interpolate": HOSTILE_WRITING[5:]}, timeout=240)
    assert counts["info"]["exit1"] > 0 and counts["interpolate"]["exit1"] > 0
    print(f"fast fuzz: {time.time() - t0:.1f} s")


@pytest.mark.slow
def test_fuzz_many(tmp_path, sources):
    """1000+ random cases per command over eight compressions, scanline, tiled, multi-part
    and data-window-smaller-than-display files (~1.5 min on 2 cores)."""
    t0 = time.time()
    counts = run_fuzz(tmp_path, sources, {
        "info": [("zip", 260), ("none", 140), ("piz", 100), ("rle", 80), ("b44", 80),
                 ("dwaa", 80), ("pxr24", 80), ("zips", 60), ("zip-tiled16", 100),
                 ("piz-tiled8", 60), ("zip-multipart", 80), ("zip-dw", 60)],
        "convert": [("zip", 320), ("none", 160), ("piz", 100), ("dwaa", 100), ("b44", 80),
                    ("zip-tiled16", 120), ("zip-multipart", 80), ("zip-dw", 60)],
        "interpolate": [("zip", 320), ("none", 160), ("piz", 100), ("dwaa", 100), ("b44", 80),
                        ("zip-tiled16", 120), ("zip-multipart", 80), ("zip-dw", 60)],
    }, seed=1000, hostile={cmd: list(HOSTILE) for cmd in ("info", "convert", "interpolate")},
        timeout=900)
    for cmd, c in counts.items():
        assert c["tried"] >= 1000, (cmd, c)
    print(f"slow fuzz: {time.time() - t0:.1f} s")


# -- real subprocesses: the exact message and exit code ------------------------------------

def _fgen(*args, timeout=300):
    return subprocess.run(FGEN + [str(a) for a in args], capture_output=True, text=True,
                          timeout=timeout)


def _main(*args) -> int:
    """fgen in this process (for the clean runs that set a test up)."""
    from fgcli.cli import main

    try:
        main([str(a) for a in args])
    except SystemExit as e:
        return e.code
    return 0


def _one_error_line(r, path, frame=None):
    assert r.returncode == 1, (r.returncode, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"Error: file {path}"), r.stderr
    if frame is not None:
        assert f"frame {frame}:" in lines[0], r.stderr
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    return lines[0]


@pytest.mark.parametrize("name, expect", [
    ("display_4TiB", "more than this machine's"),
    ("attributes_20000", "more than 10000 attributes"),
    ("data_window_1e9", "limits:resolution"),
    ("data_window_tall", "truncated or corrupt file"),
])
def test_hostile_header_real_process(tmp_path, sources, name, expect):
    seq = tmp_path / "in"
    shutil.copytree(sources("zip"), seq)
    target = seq / FRAMES[1]
    target.write_bytes(HOSTILE[name](target.read_bytes()))
    t0 = time.time()
    r = _fgen("info", seq, "--scan", timeout=60)
    line = _one_error_line(r, target, frame=1)
    assert expect in line
    assert time.time() - t0 < 30


@pytest.mark.parametrize("tw, th", [(16, 1048576), (4096, 4096), (1000000, 16)])
def test_huge_tiles_refused_before_decoding(tmp_path, sources, tw, th):
    """OpenEXR decodes whole tiles: 16x1048576 tiles on a 32x24 image took 1 GB and 2 s."""
    seq = tmp_path / "in"
    shutil.copytree(sources("zip-tiled16"), seq)
    target = seq / FRAMES[1]
    target.write_bytes(edit_header(target.read_bytes(),
                                   tiles=struct.pack("<iiB", tw, th, 0)))
    t0 = time.time()
    r = _fgen("info", seq, "--scan", timeout=60)
    assert f"tiles of {tw}x{th}" in _one_error_line(r, target, frame=1)
    assert time.time() - t0 < 20


def test_undecodable_error_message_is_an_input_error(tmp_path, sources):
    """An attribute name whose terminating NUL became 0x80: OpenEXR skips the attribute,
    opens the file and leaves an error message quoting the name, which is not UTF-8
    (OpenImageIO's geterror() then raised UnicodeDecodeError: 'internal error' before)."""
    seq = tmp_path / "in"
    shutil.copytree(sources("zip"), seq)
    target = seq / FRAMES[1]
    target.write_bytes(HOSTILE["attribute_name_unterminated"](target.read_bytes()))
    for args in (["info", seq], ["info", seq, "--scan"]):
        line = _one_error_line(_fgen(*args), target, frame=1)
        assert "corrupt header" in line and "not valid text" in line


def test_interpolate_resume_with_a_corrupt_input_keeps_outputs(tmp_path, sources):
    """Outputs already written are never touched by a failed run, and the message names the
    corrupt frame's file and number."""
    seq, out = tmp_path / "in", tmp_path / "out"
    shutil.copytree(sources("zip"), seq)
    assert _main("interpolate", seq, out, "--no-progress") == 0
    outputs = sorted(f for f in os.listdir(out) if f.endswith(".exr"))
    assert len(outputs) == 2
    os.unlink(out / outputs[1])  # the run has work left: between frames 1 and 2
    before = {f: (out / f).read_bytes() for f in os.listdir(out)}
    target = seq / FRAMES[2]
    data = target.read_bytes()
    target.write_bytes(data[:len(data) - 3000])  # truncated inside the pixel data
    r = _fgen("interpolate", seq, out, "--resume", "--no-progress")
    _one_error_line(r, target, frame=2)
    assert {f: (out / f).read_bytes() for f in os.listdir(out)} == before


def test_non_finite_pixels_are_data(tmp_path, sources):
    """NaN/Inf in every channel of a frame: read and reported, never an error or a crash."""
    seq = tmp_path / "in"
    shutil.copytree(sources("zip"), seq)
    path = str(seq / FRAMES[1])
    h = exr.read_header(path)
    p = h.parts[0]
    ch = exr.read_channels(path, [(0, c) for c in p.channels], h)
    chans = {}
    for c in p.channels:
        a = ch[(0, c)].copy()
        a[0, :4] = [np.nan, np.inf, -np.inf, np.nan]
        chans[c] = a
    exr.write_exr(path, chans, {c: ("float" if f == "float" else "half")
                                for c, f in zip(p.channels, p.formats)},
                  h.attributes, "zip", attribute_types=h.attribute_types)
    r = _fgen("info", seq, "--scan", "--json")
    assert r.returncode == 0, r.stderr
    assert sum(v["count"] for v in json.loads(r.stdout)["nonfinite"].values()) > 0
    assert _main("interpolate", seq, tmp_path / "out", "--no-progress") == 0
