/* The ray march of skyvln_eval.sim.march in C (see native_march.py): one ray at a time,
 * or on CPUs with AVX2 eight adjacent rays at a time (march_lanes), with the same results.
 *
 * Depths are meant to be bit-identical to march_reference, so every float operation below
 * is the one numpy and cv2.remap perform, in the same order and precision: build with
 * -ffp-contract=off and without -ffast-math. cv2.remap (OpenCV 5, INTER_LINEAR on float32
 * maps and a float32 layer) interpolates in float from x - floor(x), first along x, then
 * along y, with fused multiply-adds where the CPU has them (`fused`); a neighbour outside
 * the layer is the border value 0, a point whose four neighbours are all outside is 0.
 * The eight-lane code does the same IEEE operations lane by lane (the vector instructions
 * round as the scalar ones do); only its conservative bounds may differ, which decide
 * which samples to skip, never a sample's value. A height layer of whole decimetres (the
 * dataset's height_dm.png, read as float32(d) / 10) is read there as its 16-bit decimetres,
 * converted with the same division: the same heights from half the bytes, two neighbours
 * per gather.
 *
 * Reentrant: no globals, no allocation; Python calls it with the GIL released.
 */
#include <math.h>
#include <stdint.h>

#define TILE_PX 16
/* Inlined into each CPU variant below, so that its fmaf calls follow that variant's target. */
#define INLINE static inline __attribute__((always_inline))
#define CELL_PX 16.0
#define CELL_BITS 4 /* log2 of CELL_PX */

typedef struct {
    const float *data;
    int64_t rows, cols;
    /* The same heights as whole decimetres (data[i] is decimetres[i] / 10.0f, bit for bit),
     * with one readable element before the first and after the last; NULL if they are not. */
    const uint16_t *decimetres;
} Layer;

/* The max-pyramid of march._pyramid: `levels` arrays of cells_y x cells_x cells, level l
 * holding max heights over cells of CELL_PX * 2**l map pixels in its top-left corner. */
typedef struct {
    const float *data;
    int64_t levels, cells_y, cells_x;
} Pyramid;

/* native_march._cell_pairs: (cells_y + 1) x (cells_x + 1) maxima, entry (a + 1, b + 1)
 * the max over the finest cells a..a+1 x b..b+1 (cells beyond the layer are 0). */
typedef struct {
    const float *data;
    int64_t cols;
} CellPairs;

/* A camera ray in map pixels: at k = z - origin_z it is at (x0 + k sx, y0 - k sy). */
typedef struct {
    int down;
    float sx, sy, inv_dz, ground_t;
} Ray;

typedef struct {
    Layer layer;
    Pyramid pyramid;
    CellPairs pairs;
    const double *z_levels; /* the levels' heights, top down */
    const float *ks;        /* float32(z_level - origin_z) */
    const float *zs;        /* float32(z_level) */
    int64_t levels;
    double origin_z;
    float x0, y0;
    int fused;
    int nonnegative; /* whether no height is below 0 */
} March;

/* Plain comparisons: fmaxf and friends (NaN rules) may be library calls. No NaN reaches them. */
static inline float max_f(float a, float b) { return a > b ? a : b; }
static inline double max_d(double a, double b) { return a > b ? a : b; }
static inline double min_d(double a, double b) { return a < b ? a : b; }
static inline int64_t min64(int64_t a, int64_t b) { return a < b ? a : b; }

/* a + t (b - a), rounded once when fused (as OpenCV's vector kernels do with FMA). */
static inline float lerp(float a, float b, float t, int fused) {
    return fused ? fmaf(t, b - a, a) : a + t * (b - a);
}

static inline float pixel(const Layer *layer, int64_t row, int64_t col) {
    if (row < 0 || row >= layer->rows || col < 0 || col >= layer->cols) return 0.0f;
    return layer->data[row * layer->cols + col];
}

/* A point's neighbours on the layer: the pixel (ix, iy) and the three after it. */
typedef struct {
    int64_t ix, iy;
    float fx, fy;
} Spot;

/* Where cv2.remap looks (px, py) up; 0 if all four neighbours are outside the layer (the
 * sample is then the border value 0). */
static inline int locate(const Layer *layer, float px, float py, Spot *spot) {
    /* floor(px) in [-1, cols - 1] and floor(py) in [-1, rows - 1], else no neighbour is
     * inside (this also rejects NaN and values beyond the int range). */
    if (!(px >= -1.0f && px < (float)layer->cols && py >= -1.0f && py < (float)layer->rows))
        return 0;
    spot->ix = (int64_t)px;
    spot->iy = (int64_t)py;
    if ((float)spot->ix > px) spot->ix -= 1; /* truncation rounds up below 0 */
    if ((float)spot->iy > py) spot->iy -= 1;
    spot->fx = px - (float)spot->ix;
    spot->fy = py - (float)spot->iy;
    return 1;
}

/* The bilinear interpolation of cv2.remap at a located point. */
static inline float interpolate(const Layer *layer, const Spot *s, int fused) {
    int64_t ix = s->ix, iy = s->iy;
    float p00, p01, p10, p11;
    if (ix >= 0 && iy >= 0 && ix + 1 < layer->cols && iy + 1 < layer->rows) {
        const float *row = layer->data + iy * layer->cols + ix;
        p00 = row[0];
        p01 = row[1];
        p10 = row[layer->cols];
        p11 = row[layer->cols + 1];
    } else {
        p00 = pixel(layer, iy, ix);
        p01 = pixel(layer, iy, ix + 1);
        p10 = pixel(layer, iy + 1, ix);
        p11 = pixel(layer, iy + 1, ix + 1);
    }
    float top = lerp(p00, p01, s->fx, fused), bottom = lerp(p10, p11, s->fx, fused);
    return lerp(top, bottom, s->fy, fused);
}

/* The layer at map pixel (px, py) exactly as cv2.remap samples it (border value 0). */
static inline float bilinear(const Layer *layer, float px, float py, int fused) {
    Spot spot;
    return locate(layer, px, py, &spot) ? interpolate(layer, &spot, fused) : 0.0f;
}

/* An upper bound of the sample at a located point, read without its four heights (far
 * apart in a large layer): the tallest of the finest pyramid cells that can hold them
 * (pixels ix, ix + 1 lie in cells ix >> CELL_BITS and the next; ix >= -1, so the index is
 * at least 0). One read of a small array, mostly in cache. */
static inline float cells_tallest(const March *m, const Spot *s) {
    const CellPairs *p = &m->pairs;
    return p->data[((s->iy >> CELL_BITS) + 1) * p->cols + (s->ix >> CELL_BITS) + 1];
}

/* Whether a sample bounded by `tallest` is surely below height z. Bilinear samples never
 * exceed their neighbours; the slack covers rounding. */
static inline int surely_below(float tallest, double z) {
    return (double)tallest * (1.0 + 1e-5) + 1e-3 < z;
}

/* The sample at a located point bounded by `tallest`: 0 without reading the layer when
 * the bound is 0 on a layer without negative heights (the four neighbours are then all 0,
 * and cv2.remap interpolates exactly 0 between them). Most rays end on open ground. */
static inline float sample_below(const March *m, const Spot *s, float tallest) {
    if (tallest == 0.0f && m->nonnegative) return 0.0f;
    return interpolate(&m->layer, s, m->fused);
}

/* numpy's float32 operations of march_reference: px = x0 + k sx, py = y0 - k sy. */
static inline float gap_at(const March *m, const Ray *ray, int64_t j) {
    float k = m->ks[j];
    float px = m->x0 + k * ray->sx, py = m->y0 - k * ray->sy;
    Spot spot;
    float sample = 0.0f;
    if (locate(&m->layer, px, py, &spot)) sample = sample_below(m, &spot, cells_tallest(m, &spot));
    return sample - m->zs[j];
}

/* march._crossing for one ray. */
static inline float crossing(float previous_k, float before, float after, float t, float inv_dz) {
    float previous_t = previous_k * inv_dz;
    float span = before - after;
    if (!(span <= -1e-9f)) span = -1e-9f; /* np.minimum(span, -1e-9) */
    float fraction = before / span;
    if (fraction < 0.0f) fraction = 0.0f; /* np.clip(fraction, 0, 1) */
    if (fraction > 1.0f) fraction = 1.0f;
    return previous_t + fraction * (t - previous_t);
}

/* march._Frame's per-ray quantities, in the same double operations then rounded once. */
static inline Ray make_ray(const double *rays, int64_t n, int64_t i, double origin_z,
                           double mpp) {
    double dz = rays[2 * n + i];
    Ray ray;
    ray.down = dz < -1e-9;
    double safe_dz = ray.down ? dz : -1.0;
    ray.ground_t = (float)((0.0 - origin_z) / safe_dz);
    ray.inv_dz = (float)(1.0 / safe_dz);
    ray.sx = (float)(rays[i] / safe_dz / mpp);
    ray.sy = (float)(rays[n + i] / safe_dz / mpp);
    return ray;
}

/* The cell of size `size` holding map coordinate x, clamped to [0, cells): beyond the map
 * the heights are 0, which its edge cell bounds too. */
static inline int64_t cell_index(double x, double size, int64_t cells) {
    double cell = x / size;
    if (!(cell >= 0.0)) return 0; /* also NaN: the one-cell level has only cell 0 */
    if (cell >= (double)(cells - 1)) return cells - 1;
    return (int64_t)cell; /* truncation is floor here */
}

/* march._box_max: an upper bound of the layer over a map pixel box (2 px margin), the max
 * of the 2 x 2 cells of the pyramid level whose cells are at least as large as the box. */
static double box_max(const Pyramid *p, double x_min, double x_max, double y_min, double y_max) {
    double extent = max_d(x_max - x_min, y_max - y_min) + 4.0;
    int64_t level = p->levels - 1;
    if (isfinite(extent)) {
        level = 0;
        while (level < p->levels - 1 && CELL_PX * (double)(1LL << level) < extent) ++level;
    }
    double size = CELL_PX * (double)(1LL << level);
    /* This level's cells (the coarser levels fill only the array's top-left corner). */
    int64_t cells_x = (p->cells_x + (1LL << level) - 1) >> level;
    int64_t cells_y = (p->cells_y + (1LL << level) - 1) >> level;
    double edges_x[2] = {x_min - 2.0, x_max + 2.0}, edges_y[2] = {y_min - 2.0, y_max + 2.0};
    const float *cells = p->data + level * p->cells_y * p->cells_x;
    double tallest = 0.0;
    for (int a = 0; a < 2; ++a) {
        int64_t row = cell_index(edges_y[a], size, cells_y);
        for (int b = 0; b < 2; ++b) {
            int64_t col = cell_index(edges_x[b], size, cells_x);
            tallest = max_d(tallest, cells[row * p->cells_x + col]);
        }
    }
    return tallest;
}

/* An upper bound of the layer under the tile's four corner rays at every level from a to b
 * (a <= b): box_max of the box holding their points at both levels. Along a ray a point's
 * coordinates are monotone in k (so are their roundings), so the points of the levels
 * between lie in that box too; and a larger box's cells hold the smaller box's (the
 * pyramid's cells nest), so the bound is at least each level's own. For a == b it is
 * exactly that level's bound. */
static double corners_tallest(const March *m, const Ray corners[4], int64_t a, int64_t b) {
    double x_min = INFINITY, x_max = -INFINITY, y_min = INFINITY, y_max = -INFINITY;
    const int64_t ends[2] = {a, b};
    for (int e = 0; e < (a == b ? 1 : 2); ++e) {
        double k = m->z_levels[ends[e]] - m->origin_z;
        for (int c = 0; c < 4; ++c) {
            double x = (double)m->x0 + k * (double)corners[c].sx;
            double y = (double)m->y0 - k * (double)corners[c].sy;
            x_min = min_d(x_min, x);
            x_max = max_d(x_max, x);
            y_min = min_d(y_min, y);
            y_max = max_d(y_max, y);
        }
    }
    return box_max(&m->pyramid, x_min, x_max, y_min, y_max);
}

/* Whether a layer bounded by `tallest` may reach height z: bilinear samples never exceed
 * their neighbours; the slack covers rounding. */
static inline int may_reach(double tallest, double z) {
    return tallest * (1.0 + 1e-5) + 1e-3 >= z;
}

/* Levels a block of the tile start's scan passes at once, when the block's bound is below
 * its lowest level; most tiles start some 18 levels down, past four or five blocks. */
#define START_BLOCK 4

/* march._start_levels for one tile whose four corner rays all go down: the level before
 * the first one the tallest point under the corners' footprint there reaches. Blocks of
 * levels the layer surely does not reach are passed with one bound each; the block where
 * it may is scanned level by level, so the level found is the one a plain scan finds. */
static int64_t tile_start(const March *m, const Ray corners[4]) {
    for (int64_t a = 0; a < m->levels; a += START_BLOCK) {
        int64_t b = min64(a + START_BLOCK, m->levels) - 1;
        /* The block's lowest level is its last (levels go down). */
        if (b > a && !may_reach(corners_tallest(m, corners, a, b), m->z_levels[b])) continue;
        for (int64_t j = a; j <= b; ++j) {
            if (may_reach(corners_tallest(m, corners, j, j), m->z_levels[j]))
                return j > 0 ? j - 1 : 0;
        }
    }
    return 0;
}

/* The depth of one downward ray, sampled from level `start` on: no level above `start`
 * may reach the surface (the tile's bound guarantees it). The ray hits at the first level
 * where the surface is at or above the level, between it and the previous level. */
INLINE float march_ray(const March *m, const Ray *ray, int64_t start) {
    float previous = 0.0f;
    int have_previous = 0; /* whether `previous` holds the previous level's gap */
    for (int64_t j = start; j < m->levels; ++j) {
        float k = m->ks[j];
        float px = m->x0 + k * ray->sx, py = m->y0 - k * ray->sy;
        Spot spot;
        float sample = 0.0f;
        if (locate(&m->layer, px, py, &spot)) {
            float tallest = cells_tallest(m, &spot);
            if (surely_below(tallest, m->z_levels[j])) {
                have_previous = 0;
                continue;
            }
            sample = sample_below(m, &spot, tallest);
        }
        float gap = sample - m->zs[j];
        if (gap >= 0.0f) {
            float t = k * ray->inv_dz;
            if (j == 0) return t;
            float before = have_previous ? previous : gap_at(m, ray, j - 1);
            return crossing(m->ks[j - 1], before, gap, t, ray->inv_dz);
        }
        previous = gap;
        have_previous = 1;
    }
    return ray->ground_t;
}

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#define HAVE_LANES 1
#define LANES 8
#define AVX2 __attribute__((target("avx2,fma")))

/* Heights from whole decimetres, as numpy makes the layer (float32(d) / 10, one rounding). */
AVX2 static inline __m256 decimetres_m(__m256i decimetres) {
    return _mm256_div_ps(_mm256_cvtepi32_ps(decimetres), _mm256_set1_ps(10.0f));
}

/* lerp() on eight lanes: the same operations, lane by lane. */
AVX2 static inline __m256 lerp8(__m256 a, __m256 b, __m256 t, int fused) {
    __m256 d = _mm256_sub_ps(b, a);
    return fused ? _mm256_fmadd_ps(t, d, a) : _mm256_add_ps(a, _mm256_mul_ps(t, d));
}

AVX2 static inline __m256 as_mask(__m256i bits) { return _mm256_castsi256_ps(bits); }

/* The lanes set in `bits` as a mask. */
AVX2 static inline __m256 lane_mask(int bits) {
    const __m256i lanes = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    __m256i set = _mm256_and_si256(_mm256_set1_epi32(bits), lanes);
    return as_mask(_mm256_cmpeq_epi32(set, lanes));
}

/* Eight rays' Ray fields, lane by lane. Built in registers, not through per-lane arrays:
 * eight scalar stores read back as one vector stall the load (no store forwarding). */
typedef struct {
    __m256 sx, sy, inv_dz, ground_t;
    int down; /* lane bits of the rays that go down */
} Lanes;

/* make_ray() for rays i..i+LANES-1, four at a time: the same double operations. */
AVX2 static Lanes make_lanes(const double *rays, int64_t n, int64_t i, double origin_z,
                             double mpp) {
    __m128 ground_t[2], inv_dz[2], sx[2], sy[2];
    int down = 0;
    const __m256d scale = _mm256_set1_pd(mpp);
    for (int h = 0; h < 2; ++h) {
        __m256d dz = _mm256_loadu_pd(rays + 2 * n + i + 4 * h);
        __m256d is_down = _mm256_cmp_pd(dz, _mm256_set1_pd(-1e-9), _CMP_LT_OQ);
        __m256d safe_dz = _mm256_blendv_pd(_mm256_set1_pd(-1.0), dz, is_down);
        ground_t[h] = _mm256_cvtpd_ps(_mm256_div_pd(_mm256_set1_pd(0.0 - origin_z), safe_dz));
        inv_dz[h] = _mm256_cvtpd_ps(_mm256_div_pd(_mm256_set1_pd(1.0), safe_dz));
        __m256d x = _mm256_div_pd(_mm256_loadu_pd(rays + i + 4 * h), safe_dz);
        __m256d y = _mm256_div_pd(_mm256_loadu_pd(rays + n + i + 4 * h), safe_dz);
        sx[h] = _mm256_cvtpd_ps(_mm256_div_pd(x, scale));
        sy[h] = _mm256_cvtpd_ps(_mm256_div_pd(y, scale));
        down |= _mm256_movemask_pd(is_down) << (4 * h);
    }
    return (Lanes){_mm256_set_m128(sx[1], sx[0]), _mm256_set_m128(sy[1], sy[0]),
                   _mm256_set_m128(inv_dz[1], inv_dz[0]),
                   _mm256_set_m128(ground_t[1], ground_t[0]), down};
}

/* The gaps (sample - level) of eight rays at level j, lane by lane as march_ray computes
 * them: the points are located at once and, for lanes in `want`, the layer's four heights
 * gathered (a neighbour outside the layer is the border value 0). With `below` given, the
 * lanes whose bound (cells_tallest) is surely below the level are set there and not read:
 * their gap is negative, but not computed. */
AVX2 static inline __m256 level_gaps(const March *m, __m256 sx, __m256 sy, int64_t j,
                                     __m256 want, int *below) {
    const __m256 zero = _mm256_setzero_ps(), minus_one = _mm256_set1_ps(-1.0f);
    const __m256i one = _mm256_set1_epi32(1), minus_one_i = _mm256_set1_epi32(-1);
    const __m256i cols = _mm256_set1_epi32((int)m->layer.cols);
    const __m256i rows = _mm256_set1_epi32((int)m->layer.rows);
    __m256 k = _mm256_set1_ps(m->ks[j]), z = _mm256_set1_ps(m->zs[j]);
    __m256 px = _mm256_add_ps(_mm256_set1_ps(m->x0), _mm256_mul_ps(k, sx));
    __m256 py = _mm256_sub_ps(_mm256_set1_ps(m->y0), _mm256_mul_ps(k, sy));
    /* locate(): a point with a neighbour on the layer (false for NaN). */
    __m256 inside = _mm256_and_ps(
        _mm256_and_ps(_mm256_cmp_ps(px, minus_one, _CMP_GE_OQ),
                      _mm256_cmp_ps(px, _mm256_set1_ps((float)m->layer.cols), _CMP_LT_OQ)),
        _mm256_and_ps(_mm256_cmp_ps(py, minus_one, _CMP_GE_OQ),
                      _mm256_cmp_ps(py, _mm256_set1_ps((float)m->layer.rows), _CMP_LT_OQ)));
    /* Lanes off the layer sample 0; a point on it keeps their indices small. */
    px = _mm256_blendv_ps(zero, px, inside);
    py = _mm256_blendv_ps(zero, py, inside);
    __m256 floor_x = _mm256_floor_ps(px), floor_y = _mm256_floor_ps(py);
    __m256i ix = _mm256_cvttps_epi32(floor_x), iy = _mm256_cvttps_epi32(floor_y);
    /* cells_tallest(), and surely_below() in float (a slack as conservative). */
    __m256i cell = _mm256_add_epi32(
        _mm256_mullo_epi32(_mm256_add_epi32(_mm256_srai_epi32(iy, CELL_BITS), one),
                           _mm256_set1_epi32((int)m->pairs.cols)),
        _mm256_add_epi32(_mm256_srai_epi32(ix, CELL_BITS), one));
    __m256 tallest = _mm256_mask_i32gather_ps(zero, m->pairs.data, cell, inside, 4);
    __m256 read = _mm256_and_ps(want, inside);
    if (below) {
        __m256 bound = _mm256_add_ps(_mm256_mul_ps(tallest, _mm256_set1_ps(1.0f + 1e-5f)),
                                     _mm256_set1_ps(1e-3f));
        __m256 surely = _mm256_and_ps(inside, _mm256_cmp_ps(bound, z, _CMP_LT_OQ));
        *below = _mm256_movemask_ps(surely);
        read = _mm256_andnot_ps(surely, read);
    }
    /* sample_below(): a bound of 0 on a layer without negative heights is a sample of 0. */
    if (m->nonnegative) read = _mm256_andnot_ps(_mm256_cmp_ps(tallest, zero, _CMP_EQ_OQ), read);
    __m256 sample = zero;
    if (_mm256_movemask_ps(read)) {
        __m256 fx = _mm256_sub_ps(px, floor_x), fy = _mm256_sub_ps(py, floor_y);
        __m256 left = as_mask(_mm256_cmpgt_epi32(ix, minus_one_i));
        __m256 right = as_mask(_mm256_cmpgt_epi32(cols, _mm256_add_epi32(ix, one)));
        __m256 top = as_mask(_mm256_cmpgt_epi32(iy, minus_one_i));
        __m256 bottom = as_mask(_mm256_cmpgt_epi32(rows, _mm256_add_epi32(iy, one)));
        __m256i at = _mm256_add_epi32(_mm256_mullo_epi32(iy, cols), ix);
        __m256i under = _mm256_add_epi32(at, cols);
        __m256 up_left = _mm256_and_ps(read, _mm256_and_ps(top, left));
        __m256 up_right = _mm256_and_ps(read, _mm256_and_ps(top, right));
        __m256 down_left = _mm256_and_ps(read, _mm256_and_ps(bottom, left));
        __m256 down_right = _mm256_and_ps(read, _mm256_and_ps(bottom, right));
        __m256 p00, p01, p10, p11;
        if (m->layer.decimetres) {
            /* Each read takes a neighbour and the one to its right (16 bits each), from a
             * layer half the size: gathers are what this loop waits for. The padding makes
             * both reads valid for ix = -1 and ix + 1 = cols, whose outside halves are
             * masked below. */
            const int *pairs = (const int *)m->layer.decimetres;
            const __m256i none = _mm256_setzero_si256(), low = _mm256_set1_epi32(0xFFFF);
            __m256i above = _mm256_mask_i32gather_epi32(
                none, pairs, at, _mm256_castps_si256(_mm256_and_ps(read, top)), 2);
            __m256i beneath = _mm256_mask_i32gather_epi32(
                none, pairs, under, _mm256_castps_si256(_mm256_and_ps(read, bottom)), 2);
            p00 = _mm256_and_ps(up_left, decimetres_m(_mm256_and_si256(above, low)));
            p01 = _mm256_and_ps(up_right, decimetres_m(_mm256_srli_epi32(above, 16)));
            p10 = _mm256_and_ps(down_left, decimetres_m(_mm256_and_si256(beneath, low)));
            p11 = _mm256_and_ps(down_right, decimetres_m(_mm256_srli_epi32(beneath, 16)));
        } else {
            const float *data = m->layer.data;
            p00 = _mm256_mask_i32gather_ps(zero, data, at, up_left, 4);
            p01 = _mm256_mask_i32gather_ps(zero, data, _mm256_add_epi32(at, one), up_right, 4);
            p10 = _mm256_mask_i32gather_ps(zero, data, under, down_left, 4);
            p11 = _mm256_mask_i32gather_ps(zero, data, _mm256_add_epi32(under, one), down_right, 4);
        }
        __m256 upper = lerp8(p00, p01, fx, m->fused), lower = lerp8(p10, p11, fx, m->fused);
        sample = _mm256_and_ps(read, lerp8(upper, lower, fy, m->fused));
    }
    return _mm256_sub_ps(sample, z);
}

/* crossing() on eight lanes: the same operations, lane by lane. */
AVX2 static inline __m256 crossing8(float previous_k, __m256 before, __m256 after, __m256 t,
                                    __m256 inv_dz) {
    __m256 previous_t = _mm256_mul_ps(_mm256_set1_ps(previous_k), inv_dz);
    __m256 span = _mm256_sub_ps(before, after), limit = _mm256_set1_ps(-1e-9f);
    span = _mm256_blendv_ps(limit, span, _mm256_cmp_ps(span, limit, _CMP_LE_OQ));
    __m256 fraction = _mm256_div_ps(before, span);
    __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    fraction = _mm256_blendv_ps(fraction, zero, _mm256_cmp_ps(fraction, zero, _CMP_LT_OQ));
    fraction = _mm256_blendv_ps(fraction, one, _mm256_cmp_ps(fraction, one, _CMP_GT_OQ));
    return _mm256_add_ps(previous_t, _mm256_mul_ps(fraction, _mm256_sub_ps(t, previous_t)));
}

/* march_ray for eight rays of one tile row, level by level together from `start`: the
 * same depths (adjacent rays meet the surface within a level of each other, so lanes
 * rarely wait). Rays that go up get INFINITY. */
AVX2 static void march_lanes(const March *m, const Lanes *rays, int64_t start, float *out) {
    int active = rays->down; /* lanes still in flight */
    const __m256 vsx = rays->sx, vsy = rays->sy, vinv_dz = rays->inv_dz;
    const __m256 all = as_mask(_mm256_set1_epi32(-1));
    __m256 result = _mm256_blendv_ps(_mm256_set1_ps(INFINITY), rays->ground_t, lane_mask(active));
    __m256 previous = _mm256_setzero_ps();
    int have_previous = 0; /* lanes whose `previous` holds the previous level's gap */
    for (int64_t j = start; j < m->levels && active; ++j) {
        int below;
        __m256 gap = level_gaps(m, vsx, vsy, j, all, &below);
        int hits = _mm256_movemask_ps(_mm256_cmp_ps(gap, _mm256_setzero_ps(), _CMP_GE_OQ)) &
                   ~below & active;
        if (hits) {
            __m256 t = _mm256_mul_ps(_mm256_set1_ps(m->ks[j]), vinv_dz);
            __m256 depth_here = t;
            if (j > 0) {
                /* The previous level's gaps, sampled now where that level was passed. */
                int missing = hits & ~have_previous;
                __m256 before = previous;
                if (missing) {
                    __m256 lanes = lane_mask(missing);
                    __m256 sampled = level_gaps(m, vsx, vsy, j - 1, lanes, NULL);
                    before = _mm256_blendv_ps(before, sampled, lanes);
                }
                depth_here = crossing8(m->ks[j - 1], before, gap, t, vinv_dz);
            }
            result = _mm256_blendv_ps(result, depth_here, lane_mask(hits));
            active &= ~hits;
        }
        previous = gap;
        have_previous = ~below;
    }
    _mm256_storeu_ps(out, result);
}
#endif

/* All rays of one TILE_PX square tile of a view, rows [r0, r1) and columns [c0, c1) of
 * the image whose first ray is `first`. */
INLINE void march_tile(const March *m, const double *rays, int64_t n, int64_t width,
                       int64_t first, int64_t r0, int64_t r1, int64_t c0, int64_t c1,
                       double mpp, int lanes, float *depth) {
    const int64_t corner_rows[4] = {r0, r0, r1 - 1, r1 - 1};
    const int64_t corner_cols[4] = {c0, c1 - 1, c0, c1 - 1};
    Ray corners[4];
    int all_down = 1;
    for (int c = 0; c < 4; ++c) {
        corners[c] = make_ray(rays, n, first + corner_rows[c] * width + corner_cols[c],
                              m->origin_z, mpp);
        all_down &= corners[c].down;
    }
    /* A tile with rays on both sides of the horizon is sampled from the top. */
    int64_t start = all_down ? tile_start(m, corners) : 0;
    for (int64_t r = r0; r < r1; ++r) {
        int64_t c = c0;
#ifdef HAVE_LANES
        for (; lanes && c + LANES <= c1; c += LANES) {
            int64_t i = first + r * width + c;
            Lanes eight = make_lanes(rays, n, i, m->origin_z, mpp);
            march_lanes(m, &eight, start, depth + i);
        }
#endif
        for (; c < c1; ++c) {
            int64_t i = first + r * width + c;
            Ray ray = make_ray(rays, n, i, m->origin_z, mpp);
            depth[i] = ray.down ? march_ray(m, &ray, start) : INFINITY;
        }
    }
}

INLINE void march_views(const March *m, const double *rays, int64_t views, int64_t height,
                        int64_t width, double mpp, int lanes, float *depth) {
    int64_t n = views * height * width;
    for (int64_t v = 0; v < views; ++v) {
        int64_t first = v * height * width;
        for (int64_t r0 = 0; r0 < height; r0 += TILE_PX) {
            for (int64_t c0 = 0; c0 < width; c0 += TILE_PX) {
                march_tile(m, rays, n, width, first, r0, min64(r0 + TILE_PX, height), c0,
                           min64(c0 + TILE_PX, width), mpp, lanes, depth);
            }
        }
    }
}

#ifdef HAVE_LANES
/* The same code built for CPUs with FMA: fmaf is then one instruction, not a libm call. */
__attribute__((target("fma"))) static void march_views_fma(const March *m, const double *rays,
                                                          int64_t views, int64_t height,
                                                          int64_t width, double mpp,
                                                          float *depth) {
    march_views(m, rays, views, height, width, mpp, 0, depth);
}

/* And for CPUs with AVX2 (and FMA), eight rays at a time. */
AVX2 static void march_views_avx2(const March *m, const double *rays, int64_t views,
                                  int64_t height, int64_t width, double mpp, float *depth) {
    march_views(m, rays, views, height, width, mpp, 1, depth);
}
#endif

/* Planar depths (views, height, width) of rays (3, views, height, width): inf for rays that
 * go up. Returns 0. */
int skyvln_march(const double *rays, int64_t views, int64_t height, int64_t width,
                 double origin_x, double origin_y, double origin_z, double mpp, double top_m,
                 const float *heights, int64_t rows, int64_t cols, const uint16_t *decimetres,
                 const float *pyramid,
                 int64_t pyramid_levels, int64_t cells_y, int64_t cells_x, const float *pairs,
                 const double *z_levels, const float *ks, const float *zs, int64_t levels,
                 int fused, int nonnegative, int lanes, float *depth) {
    March m;
    m.layer = (Layer){heights, rows, cols, decimetres};
    m.pyramid = (Pyramid){pyramid, pyramid_levels, cells_y, cells_x};
    m.pairs = (CellPairs){pairs, cells_x + 1};
    m.z_levels = z_levels;
    m.ks = ks;
    m.zs = zs;
    m.levels = levels;
    m.origin_z = origin_z;
    m.x0 = (float)(origin_x / mpp);
    m.y0 = (float)((top_m - origin_y) / mpp);
    m.fused = fused;
    m.nonnegative = nonnegative;
#ifdef HAVE_LANES
    /* The lanes index the layer and the cell pairs with 32-bit integers. */
    int small = (rows + 1) * (cols + 1) < INT32_MAX && (cells_y + 2) * (cells_x + 2) < INT32_MAX;
    if (lanes && small && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) {
        march_views_avx2(&m, rays, views, height, width, mpp, depth);
        return 0;
    }
    if (fused && __builtin_cpu_supports("fma")) {
        march_views_fma(&m, rays, views, height, width, mpp, depth);
        return 0;
    }
#endif
    march_views(&m, rays, views, height, width, mpp, 0, depth);
    return 0;
}

/* The layer at n points, as bilinear() samples it: checked against cv2.remap on load. */
int skyvln_sample(const float *heights, int64_t rows, int64_t cols, const float *px,
                  const float *py, int64_t n, int fused, float *out) {
    Layer layer = {heights, rows, cols, NULL};
    for (int64_t i = 0; i < n; ++i) out[i] = bilinear(&layer, px[i], py[i], fused);
    return 0;
}

/* The camera rays of sensing.plane_rays for each view: component c of view v at pixel i is
 * (a[i] right[c] + forward[c]) - b[i] up[c], the operations numpy does there. `bases`
 * holds per view forward, right and up (9 doubles); `rays` is (3, views, n). Returns 0. */
int skyvln_rays(const double *a, const double *b, int64_t n, const double *bases, int64_t views,
                double *rays) {
    for (int64_t v = 0; v < views; ++v) {
        const double *forward = bases + 9 * v, *right = forward + 3, *up = forward + 6;
        for (int c = 0; c < 3; ++c) {
            double *out = rays + (c * views + v) * n;
            const double f = forward[c], r = right[c], u = up[c];
            for (int64_t i = 0; i < n; ++i) out[i] = (a[i] * r + f) - b[i] * u;
        }
    }
    return 0;
}

/* Where each of n rays (3, n) hit, in map pixels (px, py), as camera.hit_coordinates
 * computes it in numpy: the hit looked up `nudge` further along the ray, in double, then
 * divided in float32 (numpy's weak Python-float scalars); px is -1e6 (off the map) for
 * the sky. `depth_out` is the depth with anything beyond max_depth (compared in float32)
 * made inf. Returns 0. */
int skyvln_hit_coords(const double *rays, const float *depth, const double *nudge, int64_t n,
                      double origin_x, double origin_y, double mpp, double top_m,
                      float max_depth, float *px, float *py, float *depth_out) {
    const double *rx = rays, *ry = rays + n;
    const float mpp_f = (float)mpp, top_f = (float)top_m;
    for (int64_t i = 0; i < n; ++i) {
        const float d = depth[i];
        const int sky = !isfinite(d);
        const double t = sky ? 0.0 : (double)d + nudge[i];
        const float x = (float)(origin_x + t * rx[i]);
        const float y = (float)(origin_y + t * ry[i]);
        px[i] = sky ? -1e6f : x / mpp_f;
        py[i] = (top_f - y) / mpp_f;
        depth_out[i] = d > max_depth ? INFINITY : d;
    }
    return 0;
}
