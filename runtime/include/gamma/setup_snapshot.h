// A Simulation's setup as bytes and back: what `gammac run` keeps in its
// setup cache (compiler/gamma/driver/setup_cache.py, SPEC §16.1).  The surfels,
// the triangle lookup and the splat kernel are most of the setup's time and
// depend only on the mesh (its vertices, triangles and bounds), the surfel
// count, the seed and the binding of triangles to surfaces; a snapshot holds
// them together with those inputs, and a Simulation takes it only when its
// own inputs are the same, so a run set up from a snapshot is the same bit
// for bit as one set up from scratch.  The kd-trees, the BVH, the measures
// and the corner normals are built as always (they are cheap, or depend on
// the effect).
//
// The bytes are this build's own layout (element sizes are checked, not
// converted): the cache's file names carry the runtime build, so another
// build never reads them.  Parsing checks that every count and index is
// consistent (a damaged file is refused with an Error, never read out of
// bounds); the cache's checksum guards the values themselves.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "gamma/mesh.h"
#include "gamma/scene_index.h"
#include "gamma/splat.h"
#include "gamma/surfel_state.h"
#include "gamma/surfels.h"

namespace gammart {

namespace snapshot_detail {
class Reader;
class Writer;
}

// What names a mesh in the setup cache's file names: CRC-32s of its
// vertices, triangles and bounds, with their counts (a collision only
// misses the cache: SetupSnapshot::matches compares the mesh itself).
std::string mesh_fingerprint(const Mesh& mesh);

class SetupSnapshot {
public:
    // The setup of a Simulation of `mesh` with n surfels and `seed`, whose
    // surfels, index (built for `mesh` and its binding) and splat kernel are
    // given, as bytes.
    static std::vector<uint8_t> write(const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                                      const SceneIndex& index, const SplatKernel& splat);
    // `write`'s bytes written to the file descriptor `fd` as they are made
    // (no copy of the whole setup in memory); their CRC-32.  Throws
    // std::runtime_error if a write fails.
    static uint32_t write_fd(int fd, const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                             const SceneIndex& index, const SplatKernel& splat);
    // The size of `write`'s bytes (an upper bound, within a few hundred bytes).
    static size_t bytes(const Mesh& mesh, const SurfelSet& surf, const SceneIndex& index, const SplatKernel& splat);
    // Parses `write`'s bytes (copied); throws Error if they are not one
    // whole, consistent snapshot.
    SetupSnapshot(const uint8_t* data, size_t size);
    // Reads a setup cache file: `write`'s bytes, then their CRC-32
    // (little-endian uint32) and the mark "GMSC" (setup_cache.py).  Throws
    // Error if it cannot be read, is damaged or is not one whole,
    // consistent snapshot.
    static SetupSnapshot read(const std::string& path);

    // The setup a Simulation of `mesh` with `sample`'s surfels makes when
    // every triangle is on one surface (the binding of every effect with one
    // surface), made now and prepared, the surfels moved out of `sample`.
    // `gammac run` makes it on a core its start-up leaves idle, before it
    // knows the effect (prefetch.py); a Simulation takes it whole only when
    // its binding is that one (`matches`), else only its surfels.  Made
    // exactly as the Simulation makes its own setup, so a run set up from it
    // is the same bit for bit.  Throws Error if `sample` holds no surfels.
    static std::unique_ptr<SetupSnapshot> make_ahead(const Mesh& mesh, SurfelSample& sample, int threads);
    // Whether it was made by make_ahead (not read from the setup cache), and
    // in how many seconds (wall time, the sampling not included).
    bool made_ahead() const { return made_ahead_; }
    double seconds_ahead() const { return seconds_ahead_; }
    double sample_seconds() const { return sample_seconds_; }   // the sample's own
    // Whether a Simulation of this mesh, count, seed and binding would set
    // up exactly what this holds (and it has not been taken yet).
    bool matches(const Mesh& mesh, size_t n, uint64_t seed, const std::vector<int32_t>& tri_surface,
                 int n_surfaces) const;
    // Whether it would sample these surfels (another binding: the surfels
    // are the same, the lookup and the splat kernel are not).
    bool matches_surfels(const Mesh& mesh, size_t n, uint64_t seed) const;
    size_t surfels() const { return n_; }
    bool taken() const { return taken_; }

    // The surfels and the splat kernel, moved out (once).
    SurfelSet take_surfels();
    SplatKernel take_splat();
    // What a Simulation of `mesh` would build next to the snapshot, built
    // now for the binding the snapshot holds: the BVH, the kd-trees (the
    // lookup moved in) and the renders' corner normals for the default
    // shading.  `gammac run` prepares while it is still starting up, on a
    // core that is otherwise idle.  Nothing if the mesh is not the
    // snapshot's; never throws (a failure leaves it unprepared, and the
    // Simulation builds as always, reporting any error there).
    void prepare(const Mesh& mesh, int threads);
    // The same with the corner normals given: corner_normals(mesh, {},
    // kDefaultCreaseDeg), computed beforehand (read_mesh_ahead computes them
    // while it reads the snapshot); computed here if they are not 9 per
    // triangle.
    void prepare(const Mesh& mesh, int threads, std::vector<float> default_corner_normals);
    bool prepared() const { return index_ != nullptr; }
    // prepare's index and corner normals, moved out (once).
    std::unique_ptr<SceneIndex> take_index();
    std::vector<float> take_corner_normals();

    // Indexes the surfels (take_surfels' positions, their surfaces) in
    // `index`, whose geometry is built for the matching mesh and binding,
    // and moves the lookup in: afterwards `index` is what
    // SceneIndex::build_surfels would have made of these surfels.  Runs in
    // the calling thread's TBB arena.
    void adopt_index(SceneIndex& index, const float* positions, const int32_t* surfel_surface, float sigma);

private:
    SetupSnapshot() = default;
    void parse(snapshot_detail::Reader& r);
    static void write_to(snapshot_detail::Writer& w, const Mesh& mesh, uint64_t seed, const SurfelSet& surf,
                         const SceneIndex& index, const SplatKernel& splat);
    void move_lookup_into(SceneIndex& index);

    size_t n_ = 0;
    uint64_t seed_ = 0;
    int32_t n_surfaces_ = 0;
    bool taken_ = false;
    bool made_ahead_ = false;
    double seconds_ahead_ = 0, sample_seconds_ = 0;
    std::vector<float> vertices_, lo_hi_;
    std::vector<int32_t> triangles_, tri_surface_;
    SurfelSet surf_;
    SplatKernel splat_;
    std::vector<SceneIndex::TriangleLookup> lookup_tri_, lookup_cells_;
    std::vector<SceneIndex::TriangleGrid> lookup_grids_;
    std::vector<SceneIndex::PackedEntry, HugePageAllocator<SceneIndex::PackedEntry>> lookup_packed_;
    std::vector<SceneIndex::TriangleHead, HugePageAllocator<SceneIndex::TriangleHead>> lookup_head_;
    std::vector<uint32_t> lookup_cell_at_;
    std::vector<float> lookup_ball2_;
    uint64_t lookup_n_candidates_ = 0;
    std::unique_ptr<SceneIndex> index_;       // prepare's
    std::vector<float> corner_normals_;       // prepare's
};

}  // namespace gammart
