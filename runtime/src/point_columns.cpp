// Column index for exact fixed-radius queries (see gamma/point_columns.h).
#include "gamma/point_columns.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace gammart {

void PointColumns::build(const float* p, size_t n, double side) {
    start_.clear();
    key_.clear();
    x_.clear();
    y_.clear();
    z_.clear();
    id_.clear();
    n_ = n;
    if (n == 0) {
        start_.assign(2, 0);
        nu_ = nv_ = 1;
        return;
    }
    double lo[3], hi[3];
    for (int k = 0; k < 3; ++k) lo[k] = hi[k] = p[k];
    for (size_t i = 1; i < n; ++i)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], double(p[3 * i + k]));
            hi[k] = std::max(hi[k], double(p[3 * i + k]));
        }
    // Columns over the two widest axes; binary searches along the narrowest.
    int axes[3];
    axes_by_extent(lo, hi, axes);
    const double eu = hi[axes[0]] - lo[axes[0]], ev = hi[axes[1]] - lo[axes[1]];
    // At most about 2 columns per point (column_layout) and 4096 a side.
    if (!(side > 0) || !std::isfinite(side)) side = std::max(eu, ev) + 1.0;
    side = std::max({side, eu / 4096.0, ev / 4096.0});
    const ColumnLayout g = column_layout(lo, hi, axes, side, n);
    u_ = g.u, v_ = g.v, w_ = g.w;
    lo_u_ = g.lo_u, lo_v_ = g.lo_v, inv_side_ = g.inv_side;
    nu_ = g.nu, nv_ = g.nv;
    const size_t ncol = size_t(nu_) * size_t(nv_);
    bin_into_columns(p, n, u_, v_, lo_u_, lo_v_, inv_side_, nu_, nv_, start_, id_);
    // within each column: by the third coordinate (then index: a fixed order)
    for (size_t c = 0; c < ncol; ++c)
        std::sort(id_.begin() + std::ptrdiff_t(start_[c]), id_.begin() + std::ptrdiff_t(start_[c + 1]),
                  [&](uint32_t a, uint32_t b) {
                      const float za = p[3 * size_t(a) + w_], zb = p[3 * size_t(b) + w_];
                      return za < zb || (za == zb && a < b);
                  });
    // (the padding: keys past any c1, never visited)
    key_.assign(n + kGroup - 1, std::numeric_limits<float>::infinity());
    x_.assign(n + kGroup - 1, 0.0f);
    y_.assign(n + kGroup - 1, 0.0f);
    z_.assign(n + kGroup - 1, 0.0f);
    id_.resize(n + kGroup - 1, 0);
    for (size_t k = 0; k < n; ++k) {
        const size_t i = id_[k];
        key_[k] = p[3 * i + w_];
        x_[k] = p[3 * i];
        y_[k] = p[3 * i + 1];
        z_[k] = p[3 * i + 2];
    }
    finite_keys_ = std::all_of(key_.begin(), key_.begin() + std::ptrdiff_t(n), [](float w) { return std::isfinite(w); });
}

}  // namespace gammart
