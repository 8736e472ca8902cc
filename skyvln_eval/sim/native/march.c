/* The ray march of skyvln_eval.sim.march in C, one ray at a time (see native_march.py).
 *
 * Depths are meant to be bit-identical to march_reference, so every float operation below
 * is the one numpy and cv2.remap perform, in the same order and precision: build with
 * -ffp-contract=off and without -ffast-math. cv2.remap (OpenCV 5, INTER_LINEAR on float32
 * maps and a float32 layer) interpolates in float from x - floor(x), first along x, then
 * along y, with fused multiply-adds where the CPU has them (`fused`); a neighbour outside
 * the layer is the border value 0, a point whose four neighbours are all outside is 0.
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

/* march._start_levels for one tile whose four corner rays all go down: the level before
 * the first one the tallest point under the corners' footprint there reaches. */
static int64_t tile_start(const March *m, const Ray corners[4]) {
    for (int64_t j = 0; j < m->levels; ++j) {
        double k = m->z_levels[j] - m->origin_z;
        double x_min = INFINITY, x_max = -INFINITY, y_min = INFINITY, y_max = -INFINITY;
        for (int c = 0; c < 4; ++c) {
            double x = (double)m->x0 + k * (double)corners[c].sx;
            double y = (double)m->y0 - k * (double)corners[c].sy;
            x_min = min_d(x_min, x);
            x_max = max_d(x_max, x);
            y_min = min_d(y_min, y);
            y_max = max_d(y_max, y);
        }
        double tallest = box_max(&m->pyramid, x_min, x_max, y_min, y_max);
        /* Bilinear samples never exceed their neighbours; the slack covers rounding. */
        if (tallest * (1.0 + 1e-5) + 1e-3 >= m->z_levels[j]) return j > 0 ? j - 1 : 0;
    }
    return 0;
}

static inline int64_t min64(int64_t a, int64_t b) { return a < b ? a : b; }

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

/* All rays of one TILE_PX square tile of a view, rows [r0, r1) and columns [c0, c1) of
 * the image whose first ray is `first`. */
INLINE void march_tile(const March *m, const double *rays, int64_t n, int64_t width,
                       int64_t first, int64_t r0, int64_t r1, int64_t c0, int64_t c1,
                       double mpp, float *depth) {
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
        for (int64_t c = c0; c < c1; ++c) {
            int64_t i = first + r * width + c;
            Ray ray = make_ray(rays, n, i, m->origin_z, mpp);
            depth[i] = ray.down ? march_ray(m, &ray, start) : INFINITY;
        }
    }
}

INLINE void march_views(const March *m, const double *rays, int64_t views, int64_t height,
                        int64_t width, double mpp, float *depth) {
    int64_t n = views * height * width;
    for (int64_t v = 0; v < views; ++v) {
        int64_t first = v * height * width;
        for (int64_t r0 = 0; r0 < height; r0 += TILE_PX) {
            for (int64_t c0 = 0; c0 < width; c0 += TILE_PX) {
                march_tile(m, rays, n, width, first, r0, min64(r0 + TILE_PX, height), c0,
                           min64(c0 + TILE_PX, width), mpp, depth);
            }
        }
    }
}

#if defined(__x86_64__) && defined(__GNUC__)
/* The same code built for CPUs with FMA: fmaf is then one instruction, not a libm call. */
__attribute__((target("fma"))) static void march_views_fma(const March *m, const double *rays,
                                                          int64_t views, int64_t height,
                                                          int64_t width, double mpp,
                                                          float *depth) {
    march_views(m, rays, views, height, width, mpp, depth);
}
#endif

/* Planar depths (views, height, width) of rays (3, views, height, width): inf for rays that
 * go up. Returns 0. */
int skyvln_march(const double *rays, int64_t views, int64_t height, int64_t width,
                 double origin_x, double origin_y, double origin_z, double mpp, double top_m,
                 const float *heights, int64_t rows, int64_t cols, const float *pyramid,
                 int64_t pyramid_levels, int64_t cells_y, int64_t cells_x, const float *pairs,
                 const double *z_levels, const float *ks, const float *zs, int64_t levels,
                 int fused, int nonnegative, float *depth) {
    March m;
    m.layer = (Layer){heights, rows, cols};
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
#if defined(__x86_64__) && defined(__GNUC__)
    if (fused && __builtin_cpu_supports("fma")) {
        march_views_fma(&m, rays, views, height, width, mpp, depth);
        return 0;
    }
#endif
    march_views(&m, rays, views, height, width, mpp, depth);
    return 0;
}

/* The layer at n points, as bilinear() samples it: checked against cv2.remap on load. */
int skyvln_sample(const float *heights, int64_t rows, int64_t cols, const float *px,
                  const float *py, int64_t n, int fused, float *out) {
    Layer layer = {heights, rows, cols};
    for (int64_t i = 0; i < n; ++i) out[i] = bilinear(&layer, px[i], py[i], fused);
    return 0;
}
