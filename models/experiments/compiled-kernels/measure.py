"""Decode+bin and TFP's bit-sliced counter as numba kernels, against the shipped numpy code: speed, and the cost
of compiling them in every process. Not shipped (README, "Where the time goes on an AVX2-only host"); needs
`pip install numba`.
Run from the repository root:

    python models/experiments/compiled-kernels/measure.py speed     # planes/s and TFP real-time factor, alternated
    python models/experiments/compiled-kernels/measure.py compile   # seconds to import numba and compile, fresh process
"""

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from rmbvideo.bench.memory import write_random_capture
from rmbvideo.chunks import Frame
from rmbvideo.io.dat import DatGeometry, DatReader
from rmbvideo.recon.classical import Tfp, _word_dtype
from rmbvideo.sensor.binning import bin_2x2x2, bin_packed

U8, U16, U24, U32, U40, U48, U56 = (np.uint64(n) for n in (8, 16, 24, 32, 40, 48, 56))
U7, U14, U28 = np.uint64(7), np.uint64(14), np.uint64(28)
SWAP_1, SWAP_2, SWAP_4 = np.uint64(0x00AA00AA00AA00AA), np.uint64(0x0000CCCC0000CCCC), np.uint64(0x00000000F0F0F0F0)


@numba.njit(nogil=True)
def bin_stored_bytes(packed, top_rows, bottom_rows, image_bytes, single32, multi32):
    """bin_packed in one loop: the 4 bytes of 2 planes x 2 rows counted in the fields of a uint32 (SWAR)."""
    for t in range(single32.shape[0]):
        for i in range(single32.shape[1]):
            a_top, a_bottom = packed[2 * t, top_rows[i]], packed[2 * t, bottom_rows[i]]
            b_top, b_bottom = packed[2 * t + 1, top_rows[i]], packed[2 * t + 1, bottom_rows[i]]
            single_row, multi_row = single32[t, i], multi32[t, i]
            for k in range(image_bytes):
                x0, x1 = np.uint32(a_top[k]), np.uint32(a_bottom[k])
                x2, x3 = np.uint32(b_top[k]), np.uint32(b_bottom[k])
                pairs = ((x0 - ((x0 >> 1) & 0x55)) | ((x1 - ((x1 >> 1) & 0x55)) << 8)
                         | ((x2 - ((x2 >> 1) & 0x55)) << 16) | ((x3 - ((x3 >> 1) & 0x55)) << 24))
                even, odd = pairs & 0x33333333, (pairs >> 2) & 0x33333333
                even = (even & 0x00FF00FF) + ((even >> 8) & 0x00FF00FF)
                even = (even & 0xFFFF) + (even >> 16)
                odd = (odd & 0x00FF00FF) + ((odd >> 8) & 0x00FF00FF)
                odd = (odd & 0xFFFF) + (odd >> 16)
                counts = even | (odd << 8)
                counts -= (counts >> 3) & 0x1111
                multi_row[k] = (counts * np.uint32(4097)) & np.uint32(0x07070707)
                single_row[k] = ((x0 & 0x55) * np.uint32(1 + (1 << 6) + (1 << 12) + (1 << 18))) & np.uint32(0x01010101)


def numba_bin_packed(packed, image_width, flip):
    n, height, _ = packed.shape
    h2 = height // 2
    single = np.empty((n // 2, h2, image_width // 2), np.uint8)
    multi = np.empty_like(single)
    rows = np.arange(2 * h2)
    stored = height - 1 - rows if flip else rows
    bin_stored_bytes(packed, stored[0::2].copy(), stored[1::2].copy(), image_width // 8, single.view(np.uint32),
                     multi.view(np.uint32))
    return single, multi


@numba.njit(nogil=True)
def add_planes(total, planes, carry):
    """total += each plane, bit-sliced (a ripple carry over words)."""
    for p in range(planes.shape[0]):
        plane = planes[p]
        for w in range(plane.shape[0]):
            carry[w] = plane[w]
        for k in range(total.shape[0]):
            bit = total[k]
            for w in range(bit.shape[0]):
                c = carry[w]
                carry[w] = bit[w] & c
                bit[w] ^= c


@numba.njit(nogil=True)
def subtract(total, snapshot, difference, borrow):
    for w in range(borrow.shape[0]):
        borrow[w] = 0
    for k in range(total.shape[0]):
        x, y, d = total[k], snapshot[k], difference[k]
        for w in range(x.shape[0]):
            differ = x[w] ^ y[w]
            b = borrow[w]
            d[w] = differ ^ b
            borrow[w] = (~x[w] & y[w]) | (~differ & b)


@numba.njit(nogil=True)
def transpose_counts(planes, counts):
    """Per stored byte, the 8 pixels' counts (bits <= 8): an 8x8 bit-matrix transpose of the bit-planes' bytes."""
    for b in range(counts.shape[0]):
        m = (np.uint64(planes[0, b]) | (np.uint64(planes[1, b]) << U8) | (np.uint64(planes[2, b]) << U16)
             | (np.uint64(planes[3, b]) << U24) | (np.uint64(planes[4, b]) << U32) | (np.uint64(planes[5, b]) << U40)
             | (np.uint64(planes[6, b]) << U48) | (np.uint64(planes[7, b]) << U56))
        t = (m ^ (m >> U7)) & SWAP_1
        m = m ^ t ^ (t << U7)
        t = (m ^ (m >> U14)) & SWAP_2
        m = m ^ t ^ (t << U14)
        t = (m ^ (m >> U28)) & SWAP_4
        counts[b] = m ^ t ^ (t << U28)


@numba.njit(nogil=True)
def to_image(pixels, width, flip, out):
    height, image_width = out.shape
    for r in range(height):
        row = out[height - 1 - r] if flip else out[r]
        low = pixels[r * width: r * width + image_width]
        for c in range(image_width):
            row[c] = low[c]


class NumbaTotals:
    """TFP's running totals with the kernels above (windows < 256 planes)."""

    def __init__(self, window, geometry):
        self.geometry, word = geometry, _word_dtype(geometry.plane_bytes)
        self.word, self.bits = word, window.bit_length()
        words = geometry.plane_bytes // word.itemsize
        self.total = np.zeros((self.bits, words), word)
        self.carry = np.empty(words, word)
        self.difference = np.zeros((8, words), word)
        self.counts = np.empty(geometry.plane_bytes, np.uint64)

    def add(self, channels, a, b):
        if b > a:
            add_planes(self.total, channels[0][a:b].view(self.word), self.carry)

    def snapshot(self):
        return self.total.copy()

    def since(self, snapshot):
        g = self.geometry
        subtract(self.total, snapshot, self.difference[: self.bits], self.carry)
        transpose_counts(self.difference.view(np.uint8), self.counts)
        out = np.empty((g.height, g.image_width), np.float32)
        to_image(self.counts.view(np.uint8), g.width, g.flip, out)
        return [out]


class NumbaTfp(Tfp):
    def _make_totals(self, channels):
        return NumbaTotals(self._sums.window, self._geometry)

    def _frame(self, total):
        image = np.divide(total.sums[0], np.float32(total.count), out=total.sums[0])
        return Frame(index=total.index, time_s=total.centre / self._rate_hz, image=image)


def best(work, runs=3):
    work()
    return min(_timed(work) for _ in range(runs))


def _timed(work):
    began = time.perf_counter()
    work()
    return time.perf_counter() - began


def speed(rounds=5):
    rng = np.random.default_rng(0)
    packed = (rng.random((1024, 250, 400)) < 0.3).astype(np.uint8)
    packed = np.packbits(packed, axis=-1, bitorder="little")
    s0, m0 = bin_packed(packed, 400, True)
    s1, m1 = numba_bin_packed(packed, 400, True)
    assert np.array_equal(s0, s1) and np.array_equal(m0, m1) and np.array_equal(m0, bin_2x2x2(
        np.unpackbits(packed, axis=-1, bitorder="little")[:, ::-1])[1])
    with tempfile.TemporaryDirectory() as folder:
        path = write_random_capture(Path(folder) / "c.dat", 20000, 400, 250)
        chunks = list(DatReader(path, DatGeometry(400, 250)).packed_chunks(1024))

        def tfp(cls):
            method = cls(41, 20)
            frames = [f for c in chunks for f in method.push(c)] + method.flush()
            return frames

        a, b = tfp(Tfp), tfp(NumbaTfp)
        assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b)) and len(a) == len(b)
        times = {name: [] for name in ("bin numpy", "bin numba", "tfp numpy", "tfp numba")}
        for _ in range(rounds):
            times["bin numpy"].append(1024 / best(lambda: bin_packed(packed, 400, True, compiled=False)))
            times["bin numba"].append(1024 / best(lambda: numba_bin_packed(packed, 400, True)))
            times["tfp numpy"].append(1.0 / best(lambda: tfp(Tfp), 1))
            times["tfp numba"].append(1.0 / best(lambda: tfp(NumbaTfp), 1))
    for name, values in times.items():
        unit = "planes/s" if name.startswith("bin") else "x real time (1 s capture)"
        print(f"{name}: median {statistics.median(values):,.2f} {unit}  ({', '.join(f'{v:,.2f}' for v in values)})")


def compile_cost():
    code = ("import time, numpy as np\nt0 = time.perf_counter()\nimport numba\nt1 = time.perf_counter()\n"
            "import sys; sys.argv = ['x']\nfrom importlib.machinery import SourceFileLoader\n"
            f"m = SourceFileLoader('m', {str(Path(__file__).resolve())!r}).load_module()\nt2 = time.perf_counter()\n"
            "m.numba_bin_packed(np.zeros((2, 2, 1), np.uint8), 8, True)\nt3 = time.perf_counter()\n"
            "from rmbvideo.io.dat import DatGeometry\ng = DatGeometry(16, 4)\nt = m.NumbaTotals(41, g)\n"
            "t.add([np.zeros((3, 8), np.uint8)], 0, 3)\ns = t.snapshot()\nt.since(s)\nt4 = time.perf_counter()\n"
            "print(f'import numba {t1 - t0:.2f} s, compile bin kernel {t3 - t2:.2f} s, TFP kernels {t4 - t3:.2f} s')")
    print(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip())


if __name__ == "__main__":
    {"speed": speed, "compile": compile_cost}[sys.argv[1]]()
