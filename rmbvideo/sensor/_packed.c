/* The compiled kernels over spike planes, built at install where a C compiler is available (each bit for bit
 * the same as its numpy form, which stays the fallback where none was):
 *
 * - bin_packed: decode and bin packed .dat planes 2x2x2 in one pass (rmbvideo.sensor.binning.bin_packed).
 *   Each stored byte holds 8 pixels of a row, LSB first. The 4 bytes at one column of 2 planes x
 *   2 rows make 4 bins: their pair counts are added in 4-bit fields (SWAR), clamped to 7 and
 *   spread to 4 output bytes (one uint32 word); the kept pixel is bit 2m of the first plane's
 *   image-top-row byte.
 * - scan_block: a block of decoded planes' last spike at or before each plane and first spike at or
 *   after it, per pixel (TFI's search, rmbvideo.recon.classical.Tfi._scan).
 *
 * The loops are plain C over bytes, written so the compiler vectorises them; they take buffers (no
 * numpy headers at build time) and run without the GIL.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "bins are written as little-endian uint32 words; other hosts use the numpy path"
#endif

#define ROW_BLOCK 256 /* bytes of a row counted before they are spread */

/* Bin one row pair of two planes: rows ``a``, ``b`` of the first plane, ``c``, ``d`` of the
 * second, ``kept`` the first plane's image-top row (``a`` or ``b``, read only); 4 bins per byte into
 * ``single`` and ``multi``. Separate restrict parameters let the compiler vectorise the loops; on
 * x86-64 Linux one build serves every CPU, with an AVX2 clone picked at load time where it has AVX2. */
#if defined(__x86_64__) && defined(__GNUC__) && defined(__linux__)
__attribute__((target_clones("avx2", "default")))
#endif
static void bin_row(const uint8_t *restrict a, const uint8_t *restrict b, const uint8_t *restrict c,
                    const uint8_t *restrict d, const uint8_t *restrict kept, Py_ssize_t n_bytes,
                    uint32_t *restrict single, uint32_t *restrict multi)
{
    uint8_t even[ROW_BLOCK], odd[ROW_BLOCK];
    for (Py_ssize_t j0 = 0; j0 < n_bytes; j0 += ROW_BLOCK) {
        const Py_ssize_t n = n_bytes - j0 < ROW_BLOCK ? n_bytes - j0 : ROW_BLOCK;
        /* The counts in byte lanes (the widest vectors)... */
        for (Py_ssize_t j = 0; j < n; j++) {
            uint8_t pa = a[j0 + j], pb = b[j0 + j], pc = c[j0 + j], pd = d[j0 + j];
            pa -= (pa >> 1) & 0x55u; /* 2-bit fields: spikes in each column pair */
            pb -= (pb >> 1) & 0x55u;
            pc -= (pc >> 1) & 0x55u;
            pd -= (pd >> 1) & 0x55u;
            /* 4-bit fields: pairs 0 and 2 in ``e``, 1 and 3 in ``o``; each sums to <= 8 */
            uint8_t e = (pa & 0x33u) + (pb & 0x33u) + (pc & 0x33u) + (pd & 0x33u);
            uint8_t o = ((pa >> 2) & 0x33u) + ((pb >> 2) & 0x33u) + ((pc >> 2) & 0x33u) + ((pd >> 2) & 0x33u);
            even[j] = e - ((e >> 3) & 0x11u); /* clamp 8 -> 7 */
            odd[j] = o - ((o >> 3) & 0x11u);
        }
        /* ...then spread to 4 bytes a byte. Nibbles even-lo, even-hi, odd-lo, odd-hi (bins 0, 2,
         * 1, 3) -> bytes 0..3: w + (w << 12) moves the high nibbles two bytes up (no carries:
         * nibbles are <= 7). The kept bits 0, 2, 4, 6 -> bytes 0..3 by shifts of 0, 6, 12 and 18
         * in one multiply. */
        for (Py_ssize_t j = 0; j < n; j++) {
            const uint32_t w = (uint32_t)even[j] | ((uint32_t)odd[j] << 8);
            multi[j0 + j] = (w * 4097u) & 0x07070707u;
            single[j0 + j] = (((uint32_t)kept[j0 + j] & 0x55u) * 0x41041u) & 0x01010101u;
        }
    }
}

/* Bin one plane pair. ``first``/``second``: the pair's planes as stored (rows of ``row_bytes``);
 * ``single``/``multi``: (h2, 4 * image_bytes) outputs. */
static void bin_pair(const uint8_t *first, const uint8_t *second, Py_ssize_t row_bytes,
                     Py_ssize_t image_bytes, Py_ssize_t h2, int first_row, int flip,
                     uint8_t *single, uint8_t *multi)
{
    for (Py_ssize_t i = 0; i < h2; i++) {
        const Py_ssize_t stored = (first_row + 2 * i) * row_bytes;
        const uint8_t *a = first + stored, *c = second + stored;
        /* With a flip, rows are stored upside down: the image's top row of the pair is the
         * second stored one, and output rows run backwards. */
        const Py_ssize_t out_row = (flip ? h2 - 1 - i : i) * 4 * image_bytes;
        bin_row(a, a + row_bytes, c, c + row_bytes, flip ? a + row_bytes : a, image_bytes,
                (uint32_t *)(single + out_row), (uint32_t *)(multi + out_row));
    }
}

PyDoc_STRVAR(bin_packed_doc,
"bin_packed(packed, single, multi, planes, height, row_bytes, image_bytes, first_row, flip)\n"
"\n"
"Bin ``planes`` (even) stored planes of ``height`` rows x ``row_bytes`` from the contiguous\n"
"buffer ``packed`` into the contiguous (planes/2, h2, 4*image_bytes) uint8 buffers ``single``\n"
"and ``multi``, h2 = (height - first_row) // 2.");

static PyObject *py_bin_packed(PyObject *self, PyObject *args)
{
    Py_buffer packed, single, multi;
    Py_ssize_t planes, height, row_bytes, image_bytes, first_row;
    int flip;
    (void)self;
    /* y* and w* take simple buffers: C-contiguous, or the call fails here. */
    if (!PyArg_ParseTuple(args, "y*w*w*nnnnnp", &packed, &single, &multi, &planes, &height,
                          &row_bytes, &image_bytes, &first_row, &flip))
        return NULL;
    PyObject *result = NULL;
    const Py_ssize_t h2 = (height - first_row) / 2;
    const Py_ssize_t plane_bytes = height * row_bytes;
    const Py_ssize_t out_bytes = (planes / 2) * h2 * 4 * image_bytes;
    if (planes < 0 || planes % 2 || first_row < 0 || first_row > 1 || h2 < 0 || image_bytes < 0
        || image_bytes > row_bytes) {
        PyErr_SetString(PyExc_ValueError, "bin_packed: inconsistent geometry");
    } else if (packed.len < planes * plane_bytes || single.len != out_bytes || multi.len != out_bytes) {
        PyErr_SetString(PyExc_ValueError, "bin_packed: buffer sizes do not match the geometry");
    } else {
        const uint8_t *in = packed.buf;
        uint8_t *s = single.buf, *m = multi.buf;
        const Py_ssize_t pair_out = h2 * 4 * image_bytes;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t t = 0; t < planes / 2; t++)
            bin_pair(in + 2 * t * plane_bytes, in + (2 * t + 1) * plane_bytes, row_bytes, image_bytes,
                     h2, (int)first_row, flip, s + t * pair_out, m + t * pair_out);
        Py_END_ALLOW_THREADS
        result = Py_NewRef(Py_None);
    }
    PyBuffer_Release(&packed);
    PyBuffer_Release(&single);
    PyBuffer_Release(&multi);
    return result;
}

/* One block's running spike offsets, plane by plane over ``n`` pixels: ``last_in`` the last spike at or before
 * each plane as its offset + 1 (0: none), ``first_from`` the first at or after it as its offset (255: none). */
#if defined(__x86_64__) && defined(__GNUC__) && defined(__linux__)
__attribute__((target_clones("avx2", "default")))
#endif
static void scan_block(const uint8_t *restrict planes, Py_ssize_t count, Py_ssize_t n, uint8_t *restrict last_in,
                       uint8_t *restrict first_from)
{
    /* Each output byte is chosen by a mask (0xff at a spike) from both candidates, both loaded: branch-free, so the
     * loops vectorise. */
    for (Py_ssize_t k = 0; k < count; k++) {
        const uint8_t *restrict spikes = planes + k * n;
        const uint8_t *restrict before = k ? last_in + (k - 1) * n : NULL;
        uint8_t *restrict out = last_in + k * n;
        const uint8_t here = (uint8_t)(k + 1);
        for (Py_ssize_t p = 0; p < n; p++) {
            const uint8_t spike = (uint8_t)-(spikes[p] != 0);
            out[p] = (uint8_t)((here & spike) | ((before ? before[p] : 0) & ~spike));
        }
    }
    for (Py_ssize_t k = count - 1; k >= 0; k--) {
        const uint8_t *restrict spikes = planes + k * n;
        const uint8_t *restrict after = k < count - 1 ? first_from + (k + 1) * n : NULL;
        uint8_t *restrict out = first_from + k * n;
        const uint8_t here = (uint8_t)k;
        for (Py_ssize_t p = 0; p < n; p++) {
            const uint8_t spike = (uint8_t)-(spikes[p] != 0);
            out[p] = (uint8_t)((here & spike) | ((after ? after[p] : 255) & ~spike));
        }
    }
}

PyDoc_STRVAR(scan_block_doc,
"scan_block(planes, last_in, first_from, count, pixels)\n"
"\n"
"From the contiguous (count, pixels) uint8 buffer ``planes`` (nonzero: a spike), fill the contiguous\n"
"(count, pixels) uint8 buffers ``last_in`` (the last spike at or before each plane, offset + 1; 0: none)\n"
"and ``first_from`` (the first at or after it, its offset; 255: none). count <= 255.");

static PyObject *py_scan_block(PyObject *self, PyObject *args)
{
    Py_buffer planes, last_in, first_from;
    Py_ssize_t count, n;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*w*w*nn", &planes, &last_in, &first_from, &count, &n))
        return NULL;
    PyObject *result = NULL;
    if (count < 0 || count > 255 || n < 0) {
        PyErr_SetString(PyExc_ValueError, "scan_block: count must be 0..255 and pixels >= 0");
    } else if (planes.len != count * n || last_in.len != count * n || first_from.len != count * n) {
        PyErr_SetString(PyExc_ValueError, "scan_block: buffer sizes do not match count x pixels");
    } else {
        Py_BEGIN_ALLOW_THREADS
        scan_block(planes.buf, count, n, last_in.buf, first_from.buf);
        Py_END_ALLOW_THREADS
        result = Py_NewRef(Py_None);
    }
    PyBuffer_Release(&planes);
    PyBuffer_Release(&last_in);
    PyBuffer_Release(&first_from);
    return result;
}

static PyMethodDef methods[] = {
    {"bin_packed", py_bin_packed, METH_VARARGS, bin_packed_doc},
    {"scan_block", py_scan_block, METH_VARARGS, scan_block_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_packed",
    "Compiled kernels over spike planes: decode+bin of stored .dat planes, TFI's block scan.", -1, methods,
};

/* Raised with every change of a kernel's arguments or results: Python uses a build of another version (a
 * source tree updated without reinstalling) as if none were built (rmbvideo.sensor.compiled). */
#define KERNELS_VERSION 2

PyMODINIT_FUNC PyInit__packed(void)
{
    PyObject *m = PyModule_Create(&module);
    if (m != NULL && PyModule_AddIntConstant(m, "VERSION", KERNELS_VERSION) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
