// SetupSnapshot: a Simulation's surfels, triangle lookup and splat kernel as
// bytes and back (see setup_snapshot.h).
//
// Layout: a header (magic, format version, byte-order mark, surfel count,
// seed, surface count, section count), then the sections in a fixed order,
// each a tag, its element size, its element count and its elements, padded
// to 8 bytes.  The element size of every section is checked against this
// build's structs, so a layout change refuses old bytes instead of misreading
// them.
#include "gamma/setup_snapshot.h"

#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <tbb/task_group.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>

#include "gamma/error.h"
#include "gamma/shading.h"
#include "gamma/threads.h"

namespace gammart {
namespace snapshot_detail {

constexpr char kMagic[8] = {'G', 'A', 'M', 'S', 'E', 'T', 'U', 'P'};
constexpr uint32_t kFormat = 1, kByteOrder = 0x01020304u;
// A cache file (setup_cache.py): the snapshot, then the CRC-32 of it
// (little-endian uint32) and this mark.
constexpr char kTrailerMark[4] = {'G', 'M', 'S', 'C'};
constexpr size_t kTrailerBytes = 8;

// The sections, in the order they are written.
enum Section : uint32_t {
    kLoHi = 1, kVertices, kTriangles, kTriSurface, kPosition, kNormal, kSurfelTriangle, kRMax,
    kSplatOffset, kSplatSource, kSplatWeight, kSplatMean, kLookupTri, kLookupGrids, kLookupCells,
    kLookupPacked, kLookupHead, kLookupCellAt, kLookupBall2, kLookupCandidates, kSectionEnd
};

struct Header {
    char magic[8];
    uint32_t format, byte_order;
    uint64_t surfels, seed;
    int32_t surfaces;
    uint32_t sections;
};
struct SectionHeader {
    uint32_t tag, element_size;
    uint64_t count;
};

// Writes a snapshot into memory, or straight to a file descriptor (then the
// CRC-32 of what it wrote is kept, for the cache file's trailer): the cache
// keeps a setup (tens of MB) without first copying it into fresh memory,
// which cost most of the write.
class Writer {
public:
    explicit Writer(std::vector<uint8_t>& out) : out_(&out) {}
    explicit Writer(int fd) : fd_(fd) { buffer_.reserve(kBuffered); }
    void raw(const void* p, size_t bytes) {
        const auto* b = static_cast<const uint8_t*>(p);
        written_ += bytes;
        if (out_) {
            out_->insert(out_->end(), b, b + bytes);
            return;
        }
        for (size_t k = 0; k < bytes; k += size_t(1) << 30)   // zlib's length is 32 bits
            crc_ = crc32(crc_, b + k, uInt(std::min(bytes - k, size_t(1) << 30)));
        if (bytes >= kBuffered) {                             // large sections: straight from the arrays
            flush();
            write_all(b, bytes);
        } else {
            buffer_.insert(buffer_.end(), b, b + bytes);
            if (buffer_.size() >= kBuffered) flush();
        }
    }
    template <typename T>
    void section(Section tag, const T* data, size_t count) {
        const SectionHeader h{tag, uint32_t(sizeof(T)), uint64_t(count)};
        raw(&h, sizeof h);
        if (count) raw(data, count * sizeof(T));
        static constexpr uint8_t kZeros[8] = {};
        raw(kZeros, (8 - written_ % 8) % 8);
    }
    template <typename V>
    void section(Section tag, const V& v) {
        section(tag, v.data(), v.size());
    }
    // Writes what is buffered; the CRC-32 of everything written.
    uLong finish() {
        flush();
        return crc_;
    }

private:
    static constexpr size_t kBuffered = size_t(1) << 16;
    void flush() {
        if (!buffer_.empty()) write_all(buffer_.data(), buffer_.size());
        buffer_.clear();
    }
    void write_all(const uint8_t* p, size_t bytes) {
        while (bytes > 0) {
            const ssize_t n = ::write(fd_, p, std::min(bytes, size_t(1) << 30));
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) throw std::runtime_error(std::string("setup snapshot: cannot write: ") + std::strerror(errno));
            p += n;
            bytes -= size_t(n);
        }
    }
    std::vector<uint8_t>* out_ = nullptr;
    int fd_ = -1;
    std::vector<uint8_t> buffer_;
    size_t written_ = 0;
    uLong crc_ = crc32(0L, Z_NULL, 0);
};

// Reads a snapshot from memory, or from a file (then the CRC-32 of what it
// read is kept, for the cache file's trailer).
class Reader {
public:
    Reader(const uint8_t* data, size_t size) : p_(data), left_(size) {}
    Reader(std::FILE* file, size_t size) : file_(file), left_(size) {}
    void raw(void* dst, size_t bytes) {
        if (left_ < bytes) fail("it ends early");
        if (file_) {
            if (std::fread(dst, 1, bytes, file_) != bytes) {
                if (std::ferror(file_)) cannot_read();
                fail("it ends early");
            }
            // zlib's length is 32 bits: large sections in pieces
            for (size_t k = 0; k < bytes; k += size_t(1) << 30)
                crc_ = crc32(crc_, static_cast<const Bytef*>(dst) + k, uInt(std::min(bytes - k, size_t(1) << 30)));
        } else if (bytes) {
            std::memcpy(dst, p_, bytes);
            p_ += bytes;
        }
        left_ -= bytes;
        read_ += bytes;
    }
    // The next section, which must be `tag` with elements of T; into v.
    template <typename V>
    void section(Section tag, V& v) {
        using T = typename V::value_type;
        SectionHeader h{};
        raw(&h, sizeof h);
        if (h.tag != tag) fail("section " + std::to_string(tag) + " is missing");
        if (h.element_size != sizeof(T)) fail("section " + std::to_string(tag) + " has another layout");
        if (h.count > left_ / sizeof(T)) fail("it ends early");
        v.resize(size_t(h.count));
        if (h.count) raw(v.data(), size_t(h.count) * sizeof(T));
        uint8_t pad[8];
        raw(pad, (8 - read_ % 8) % 8);
    }
    template <typename T>
    T scalar(Section tag) {
        std::vector<T> v;
        section(tag, v);
        if (v.size() != 1) fail("section " + std::to_string(tag) + " is not one value");
        return v[0];
    }
    bool at_end() const { return left_ == 0; }
    uLong crc() const { return crc_; }
    // What is in the bytes: gammart::Error (ValueError in Python).
    [[noreturn]] static void fail(const std::string& why) { throw Error("setup snapshot: " + why); }
    // A file that cannot be read (not what is in it): std::runtime_error.
    [[noreturn]] static void cannot_read() {
        throw std::runtime_error("setup snapshot: the file cannot be read");
    }

private:
    const uint8_t* p_ = nullptr;
    std::FILE* file_ = nullptr;
    size_t left_ = 0, read_ = 0;
    uLong crc_ = crc32(0L, Z_NULL, 0);
};

template <typename T>
void one(Writer& w, Section tag, T value) {
    w.section(tag, &value, 1);
}

}  // namespace snapshot_detail

using namespace snapshot_detail;

size_t SetupSnapshot::bytes(const Mesh& mesh, const SurfelSet& surf, const SceneIndex& index,
                            const SplatKernel& splat) {
    // each section padded to 8 bytes; 8 more per section bound the padding
    return sizeof(Header) + (sizeof(SectionHeader) + 8) * (kSectionEnd - 1) + 4 * mesh.vertices.size() +
           4 * mesh.triangles.size() + 4 * index.tri_surface_.size() + 4 * surf.position.size() +
           4 * surf.normal.size() + 4 * surf.triangle.size() + 4 * splat.offset.size() + 4 * splat.source.size() +
           4 * splat.weight.size() +
           sizeof(SceneIndex::TriangleLookup) * (index.lookup_tri_.size() + index.lookup_cells_.size()) +
           sizeof(SceneIndex::TriangleGrid) * index.lookup_grids_.size() +
           sizeof(SceneIndex::PackedEntry) * index.lookup_packed_.size() +
           sizeof(SceneIndex::TriangleHead) * index.lookup_head_.size() +
           4 * (index.lookup_cell_at_.size() + index.lookup_ball2_.size());
}

std::string mesh_fingerprint(const Mesh& mesh) {
    auto crc = [](const void* data, size_t bytes) {
        uLong c = crc32(0L, Z_NULL, 0);
        for (size_t k = 0; k < bytes; k += size_t(1) << 30)
            c = crc32(c, static_cast<const Bytef*>(data) + k, uInt(std::min(bytes - k, size_t(1) << 30)));
        return uint32_t(c);
    };
    char text[96];
    std::snprintf(text, sizeof text, "%zu-%zu-%08x-%08x-%08x", mesh.num_vertices(), mesh.num_triangles(),
                  crc(mesh.vertices.data(), mesh.vertices.size() * sizeof(float)),
                  crc(mesh.triangles.data(), mesh.triangles.size() * sizeof(int32_t)),
                  crc(mesh.lo.data(), 3 * sizeof(float)) ^ crc(mesh.hi.data(), 3 * sizeof(float)));
    return text;
}

std::vector<uint8_t> SetupSnapshot::write(const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                                          const SceneIndex& index, const SplatKernel& splat) {
    std::vector<uint8_t> out;
    out.reserve(bytes(mesh, surf, index, splat));
    Writer w(out);
    write_to(w, mesh, seed, surf, index, splat);
    return out;
}

uint32_t SetupSnapshot::write_fd(int fd, const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                                 const SceneIndex& index, const SplatKernel& splat) {
    Writer w(fd);
    write_to(w, mesh, seed, surf, index, splat);
    return uint32_t(w.finish());
}

void SetupSnapshot::write_to(Writer& w, const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                             const SceneIndex& index, const SplatKernel& splat) {
    Header h{};
    std::memcpy(h.magic, kMagic, sizeof kMagic);
    h.format = kFormat;
    h.byte_order = kByteOrder;
    h.surfels = surf.triangle.size();
    h.seed = seed;
    h.surfaces = index.n_surfaces_;
    h.sections = kSectionEnd - 1;
    w.raw(&h, sizeof h);
    const float lo_hi[6] = {mesh.lo[0], mesh.lo[1], mesh.lo[2], mesh.hi[0], mesh.hi[1], mesh.hi[2]};
    w.section(kLoHi, lo_hi, 6);
    w.section(kVertices, mesh.vertices);
    w.section(kTriangles, mesh.triangles);
    w.section(kTriSurface, index.tri_surface_);
    w.section(kPosition, surf.position);
    w.section(kNormal, surf.normal);
    w.section(kSurfelTriangle, surf.triangle);
    one(w, kRMax, surf.r_max);
    w.section(kSplatOffset, splat.offset);
    w.section(kSplatSource, splat.source);
    w.section(kSplatWeight, splat.weight);
    one(w, kSplatMean, splat.mean_neighbours);
    w.section(kLookupTri, index.lookup_tri_);
    w.section(kLookupGrids, index.lookup_grids_);
    w.section(kLookupCells, index.lookup_cells_);
    w.section(kLookupPacked, index.lookup_packed_);
    {
        // copied member by member into zeroed heads: no byte of the file is
        // uninitialised padding
        std::vector<SceneIndex::TriangleHead> heads(index.lookup_head_.size());
        std::memset(static_cast<void*>(heads.data()), 0, heads.size() * sizeof(SceneIndex::TriangleHead));
        for (size_t t = 0; t < heads.size(); ++t) {
            const SceneIndex::TriangleHead& from = index.lookup_head_[t];
            SceneIndex::TriangleHead& to = heads[t];
            to.cx = from.cx, to.cy = from.cy, to.cz = from.cz, to.reach2 = from.reach2;
            to.count = from.count, to.more = from.more;
            for (uint32_t k = 0; k < SceneIndex::kInlineCandidates; ++k) to.first[k] = from.first[k];
        }
        w.section(kLookupHead, heads);
    }
    w.section(kLookupCellAt, index.lookup_cell_at_);
    w.section(kLookupBall2, index.lookup_ball2_);
    one(w, kLookupCandidates, uint64_t(index.lookup_n_candidates_));
}

SetupSnapshot::SetupSnapshot(const uint8_t* data, size_t size) {
    Reader r(data, size);
    parse(r);
}

SetupSnapshot SetupSnapshot::read(const std::string& path) {
    std::FILE* f = std::fopen(path.c_str(), "rb");
    if (!f) Reader::cannot_read();
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> closing(f, std::fclose);
    struct stat st {};
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode) || size_t(st.st_size) < kTrailerBytes)
        Reader::fail(path + " is not a whole cache file");
    // big reads straight into the vectors: no buffer of the stdio's own
    std::setvbuf(f, nullptr, _IONBF, 0);
    SetupSnapshot snap;
    Reader r(f, size_t(st.st_size) - kTrailerBytes);
    snap.parse(r);
    uint32_t trailer[2];
    if (std::fread(trailer, 1, sizeof trailer, f) != sizeof trailer) {
        if (std::ferror(f)) Reader::cannot_read();
        Reader::fail("it ends early");
    }
    if (std::memcmp(&trailer[1], kTrailerMark, 4) != 0 || trailer[0] != uint32_t(r.crc()))
        Reader::fail(path + " is damaged (its checksum differs)");
    return snap;
}

void SetupSnapshot::parse(Reader& r) {
    using Fail = Reader;
    Header h{};
    r.raw(&h, sizeof h);
    if (std::memcmp(h.magic, kMagic, sizeof kMagic) != 0) Fail::fail("not a setup snapshot");
    if (h.format != kFormat || h.byte_order != kByteOrder) Fail::fail("another format or byte order");
    if (h.sections != kSectionEnd - 1) Fail::fail("another set of sections");
    n_ = size_t(h.surfels);
    seed_ = h.seed;
    n_surfaces_ = h.surfaces;
    r.section(kLoHi, lo_hi_);
    r.section(kVertices, vertices_);
    r.section(kTriangles, triangles_);
    r.section(kTriSurface, tri_surface_);
    r.section(kPosition, surf_.position);
    r.section(kNormal, surf_.normal);
    r.section(kSurfelTriangle, surf_.triangle);
    surf_.r_max = r.scalar<double>(kRMax);
    r.section(kSplatOffset, splat_.offset);
    r.section(kSplatSource, splat_.source);
    r.section(kSplatWeight, splat_.weight);
    splat_.mean_neighbours = r.scalar<double>(kSplatMean);
    r.section(kLookupTri, lookup_tri_);
    r.section(kLookupGrids, lookup_grids_);
    r.section(kLookupCells, lookup_cells_);
    r.section(kLookupPacked, lookup_packed_);
    r.section(kLookupHead, lookup_head_);
    r.section(kLookupCellAt, lookup_cell_at_);
    r.section(kLookupBall2, lookup_ball2_);
    lookup_n_candidates_ = r.scalar<uint64_t>(kLookupCandidates);
    if (!r.at_end()) Fail::fail("bytes follow the last section");

    // Every count and index the simulation follows, checked: the snapshot
    // is then safe to use whatever its values.
    const size_t n = n_, m = triangles_.size() / 3, nv = vertices_.size() / 3;
    auto require = [](bool ok, const char* what) {
        if (!ok) Fail::fail(std::string("inconsistent ") + what);
    };
    require(lo_hi_.size() == 6 && vertices_.size() % 3 == 0 && triangles_.size() % 3 == 0, "mesh");
    for (int32_t v : triangles_) require(v >= 0 && size_t(v) < nv, "mesh triangles");
    require(n_surfaces_ > 0 && tri_surface_.size() == m, "binding");
    for (int32_t s : tri_surface_) require(s >= 0 && s < n_surfaces_, "binding");
    require(n > 0 && surf_.position.size() == 3 * n && surf_.normal.size() == 3 * n && surf_.triangle.size() == n,
            "surfels");
    for (int32_t t : surf_.triangle) require(t >= 0 && size_t(t) < m, "surfel triangles");
    require(splat_.offset.size() == n + 1 && splat_.offset[0] == 0 && splat_.source.size() == splat_.offset[n] &&
                splat_.weight.size() == splat_.source.size(),
            "splat kernel");
    for (size_t j = 0; j < n; ++j) require(splat_.offset[j] <= splat_.offset[j + 1], "splat kernel");
    for (uint32_t s : splat_.source) require(s < n, "splat kernel sources");
    require(lookup_tri_.size() == m && lookup_head_.size() == m && lookup_ball2_.size() == m &&
                lookup_cell_at_.size() == lookup_cells_.size(),
            "lookup");
    const size_t packed = lookup_packed_.size();
    // each packed entry belongs to one head or cell at most (as written):
    // every entry is then checked once
    std::vector<uint8_t> claimed(packed, 0);
    auto entries = [&](size_t at, size_t count) {
        require(at <= packed && count <= packed - at, "lookup entries");
        for (size_t k = at; k < at + count; ++k) {
            require(!claimed[k], "lookup entries");
            claimed[k] = 1;
        }

    };
    auto candidates = [&](size_t at, size_t count) {
        entries(at, count);
        for (size_t k = at; k < at + count; ++k) require(lookup_packed_[k].id < n, "lookup ids");
    };
    constexpr uint32_t K = SceneIndex::kInlineCandidates;
    for (const SceneIndex::TriangleHead& head : lookup_head_) {
        if (head.count) {
            for (uint32_t k = 0; k < std::min(head.count, K); ++k) require(head.first[k].id < n, "lookup ids");
            if (head.count > K) candidates(head.more, head.count - K);
        } else if (head.more != SceneIndex::kNoBlock) {
            require((head.more & SceneIndex::kGridBit) &&
                        (head.more & ~SceneIndex::kGridBit) < lookup_grids_.size(),
                    "lookup grids");
        }
    }
    for (const SceneIndex::TriangleLookup& L : lookup_tri_)
        require(L.grid == SceneIndex::kNoGrid || L.grid < lookup_grids_.size(), "lookup grids");
    for (const SceneIndex::TriangleGrid& g : lookup_grids_)
        require(g.s > 0 && g.s <= SceneIndex::kMaxGridSide && g.first <= lookup_cells_.size() &&
                    2 * size_t(g.s) * g.s <= lookup_cells_.size() - g.first,
                "lookup grids");
    for (uint32_t at : lookup_cell_at_) {
        if (at == SceneIndex::kNoBlock) continue;
        require(at < packed, "lookup cells");
        entries(size_t(at), 1);   // the cell's header entry
        candidates(size_t(at) + 1, lookup_packed_[at].id);
    }
}

bool SetupSnapshot::matches(const Mesh& mesh, size_t n, uint64_t seed, const std::vector<int32_t>& tri_surface,
                            int n_surfaces) const {
    return matches_surfels(mesh, n, seed) && n_surfaces == n_surfaces_ && tri_surface == tri_surface_;
}

bool SetupSnapshot::matches_surfels(const Mesh& mesh, size_t n, uint64_t seed) const {
    // everything of the mesh the sampling and the lookup read
    // compared as bytes: -0.0 and 0.0 are different inputs to the sampling
    auto same = [](const auto& a, const auto& b) {
        return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
    };
    return !taken_ && n == n_ && seed == seed_ && std::memcmp(lo_hi_.data(), mesh.lo.data(), 3 * sizeof(float)) == 0 &&
           std::memcmp(lo_hi_.data() + 3, mesh.hi.data(), 3 * sizeof(float)) == 0 && same(mesh.vertices, vertices_) &&
           same(mesh.triangles, triangles_);
}

SurfelSet SetupSnapshot::take_surfels() {
    taken_ = true;
    index_.reset();   // prepared for the snapshot's binding: a Simulation taking only the surfels builds its own
    std::vector<float>().swap(corner_normals_);
    return std::move(surf_);
}

SplatKernel SetupSnapshot::take_splat() {
    taken_ = true;
    return std::move(splat_);
}

void SetupSnapshot::adopt_index(SceneIndex& index, const float* positions, const int32_t* surfel_surface,
                                float sigma) {
    taken_ = true;
    index.index_surfels(positions, surfel_surface, n_, sigma);
    move_lookup_into(index);
}

void SetupSnapshot::move_lookup_into(SceneIndex& index) {
    index.lookup_tri_ = std::move(lookup_tri_);
    index.lookup_grids_ = std::move(lookup_grids_);
    index.lookup_cells_ = std::move(lookup_cells_);
    index.lookup_packed_ = std::move(lookup_packed_);
    index.lookup_head_ = std::move(lookup_head_);
    index.lookup_cell_at_ = std::move(lookup_cell_at_);
    index.lookup_ball2_ = std::move(lookup_ball2_);
    index.lookup_n_candidates_ = size_t(lookup_n_candidates_);
    index.lookup_reused_ = 0;
}

void SetupSnapshot::prepare(const Mesh& mesh, int threads) {
    prepare(mesh, threads, {});
}

void SetupSnapshot::prepare(const Mesh& mesh, int threads, std::vector<float> default_corner_normals) {
    if (taken_ || index_ || !matches_surfels(mesh, n_, seed_)) return;
    try {
        auto index = std::make_unique<SceneIndex>();
        index->build_geometry(mesh, tri_surface_, n_surfaces_);
        std::vector<int32_t> surfel_surface(n_);
        for (size_t i = 0; i < n_; ++i) surfel_surface[i] = tri_surface_[size_t(surf_.triangle[i])];
        // the Simulation's smoothing width, computed as it computes it
        const float sigma = float(std::sqrt(mesh.area() / double(n_)));
        std::vector<float> normals = std::move(default_corner_normals);
        const bool have_normals = normals.size() == 9 * mesh.num_triangles();
        run_with_threads(threads, [&] {
            index->index_surfels(surf_.position.data(), surfel_surface.data(), n_, sigma);
            if (!have_normals) normals = corner_normals(mesh, {}, kDefaultCreaseDeg);
        });
        // the lookup last: a failure above leaves the snapshot whole
        move_lookup_into(*index);
        index_ = std::move(index);
        corner_normals_ = std::move(normals);
    } catch (const std::exception&) {
        index_.reset();
    }
}

namespace {
// As the Simulation: the splat kernel beside the triangle lookup up to this
// many surfels, after it above (their temporaries together; simulation.cpp).
constexpr size_t kSplatBesideMaxSurfels = 500000;
}  // namespace

std::unique_ptr<SetupSnapshot> SetupSnapshot::make_ahead(const Mesh& mesh, SurfelSample& sample, int threads) {
    if (!sample.ok() || !sample.matches(mesh, sample.count(), sample.seed()))
        throw Error("setup ahead: the sample holds no surfels of this mesh");
    const auto t0 = std::chrono::steady_clock::now();
    std::unique_ptr<SetupSnapshot> s(new SetupSnapshot());
    const size_t n = sample.count();
    s->n_ = n;
    s->seed_ = sample.seed();
    s->n_surfaces_ = 1;
    s->made_ahead_ = true;
    s->sample_seconds_ = sample.seconds();
    s->vertices_ = mesh.vertices;
    s->triangles_ = mesh.triangles;
    s->lo_hi_ = {mesh.lo[0], mesh.lo[1], mesh.lo[2], mesh.hi[0], mesh.hi[1], mesh.hi[2]};
    s->tri_surface_.assign(mesh.triangles.size() / 3, 0);
    // What Simulation::Simulation does for this binding, in its order (the
    // BVH first at one thread, beside the rest up to the kd-trees at more).
    auto index = std::make_unique<SceneIndex>();
    auto build_geometry = [&] { index->build_geometry(mesh, s->tri_surface_, 1); };
    std::unique_ptr<ThreadBeside> geometry;
    if (resolve_threads(threads) == 1)
        build_geometry();
    else
        geometry = std::make_unique<ThreadBeside>(build_geometry);
    std::vector<float> normals;
    run_with_threads(threads, [&] {
        tbb::task_group beside;
        try {
            beside.run([&] { normals = corner_normals(mesh, {}, kDefaultCreaseDeg); });
            s->surf_ = sample.take();
            const std::vector<int32_t> surfel_surface(n, 0);
            const float sigma = float(std::sqrt(mesh.area() / double(n)));
            auto splat = [&] {
                s->splat_ = build_splat_kernel(s->surf_.position.data(), s->surf_.normal.data(),
                                               surfel_surface.data(), n, sigma);
            };
            const bool splat_beside = n <= kSplatBesideMaxSurfels;
            if (splat_beside) beside.run(splat);
            if (geometry) geometry->wait();
            index->build_surfels(s->surf_.position.data(), surfel_surface.data(), n, sigma, threads);
            if (!splat_beside) splat();
            beside.wait();
        } catch (...) {
            beside.cancel();
            beside.wait();
            throw;
        }
    });
    s->index_ = std::move(index);
    s->corner_normals_ = std::move(normals);
    s->seconds_ahead_ = seconds_since(t0);
    return s;
}

std::unique_ptr<SceneIndex> SetupSnapshot::take_index() {
    taken_ = true;
    return std::move(index_);
}

std::vector<float> SetupSnapshot::take_corner_normals() {
    return std::move(corner_normals_);
}

}  // namespace gammart
