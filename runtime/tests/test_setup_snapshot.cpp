// SetupSnapshot: a setup taken from an earlier one's bytes is the same setup,
// taken only when it is this setup's, and damaged bytes are refused.
#include <gtest/gtest.h>

#include <cstring>
#include <functional>
#include <string>

#include "gamma/error.h"
#include "gamma/setup_snapshot.h"
#include "gamma/simulation.h"
#include "gamma/surfel_state.h"
#include "helpers.h"
#include "setup_helpers.h"

using namespace gammart;
using gamma_test::expect_error;
using gamma_test::expect_same_iterations;
using gamma_test::expect_same_setup;

namespace {

Config bunny_config(int threads, int surfaces = 2) {
    return gamma_test::deposit_config(6000, 11, threads, surfaces, {GAMMA_EVENT_HIT, GAMMA_EVENT_SETTLE});
}

// The bunny, its triangles bound to two surfaces (by the side of x = mean).
struct Bunny {
    Mesh mesh = Mesh::load(std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj");
    std::vector<int32_t> binding;
    Bunny() {
        double mean = 0;
        for (size_t v = 0; v < mesh.num_vertices(); ++v) mean += mesh.vertices[3 * v];
        mean /= double(mesh.num_vertices());
        for (size_t t = 0; t < mesh.num_triangles(); ++t)
            binding.push_back(mesh.vertices[3 * size_t(mesh.triangles[3 * t])] > mean ? 1 : 0);
    }
};

}  // namespace

TEST(SetupSnapshot, ASetupFromItsSnapshotIsTheSameSetupAndTracesTheSameRows) {
    const Bunny bunny;
    for (int threads : {1, 2}) {
        Config c = bunny_config(threads);
        c.triangle_surface = bunny.binding;
        Simulation fresh(bunny.mesh, c);
        EXPECT_EQ(fresh.from_snapshot(), Simulation::FromSnapshot::Nothing);
        const std::vector<uint8_t> bytes = fresh.setup_snapshot();
        // the size told beforehand bounds it closely (what the cache checks before making one)
        EXPECT_LE(bytes.size(), fresh.setup_snapshot_bytes());
        EXPECT_GE(bytes.size() + 8 * 32, fresh.setup_snapshot_bytes());
        // the snapshot of a setup made at one thread count serves the other
        Config other = c;
        other.threads = 3 - threads;
        SetupSnapshot snap(bytes.data(), bytes.size());
        EXPECT_EQ(snap.surfels(), size_t(c.surfels));
        // prepared (BVH, kd-trees, corner normals built ahead) at 2 threads, unprepared at 1
        if (threads == 2) {
            snap.prepare(bunny.mesh, 1);
            EXPECT_TRUE(snap.prepared());
        }
        Simulation restored(bunny.mesh, other, nullptr, &snap);
        EXPECT_EQ(*restored.corner_normals(), *fresh.corner_normals());
        EXPECT_EQ(restored.from_snapshot(), Simulation::FromSnapshot::Setup);
        EXPECT_TRUE(snap.taken());
        expect_same_setup(fresh, restored);
        // the restored setup's own snapshot is the same bytes
        EXPECT_EQ(restored.setup_snapshot(), bytes);
        expect_same_iterations(fresh, restored);
        double deposited = 0;
        for (size_t i = 0; i < fresh.num_surfels(); ++i) deposited += fresh.rows()[4 * i + 3];
        EXPECT_GT(deposited, 1000.0);   // the rows compared hold the deposits
        // a snapshot is taken once: a second setup from it builds its own
        Simulation again(bunny.mesh, c, nullptr, &snap);
        EXPECT_EQ(again.from_snapshot(), Simulation::FromSnapshot::Nothing);
        expect_same_setup(fresh, again);
    }
}

TEST(SetupSnapshot, ASetupMadeAheadForOneSurfaceIsTheSimulationsOwnOrGivesOnlyItsSurfels) {
    const Bunny bunny;
    for (int threads : {1, 2}) {
        // one surface: every triangle on it, the binding a setup made ahead assumes
        Config one = bunny_config(threads, 1);
        Simulation fresh(bunny.mesh, one);
        SurfelSample sample(bunny.mesh, size_t(one.surfels), one.seed, 3 - threads);
        auto ahead = SetupSnapshot::make_ahead(bunny.mesh, sample, 3 - threads);
        EXPECT_FALSE(sample.ok());                      // its surfels moved into the setup
        EXPECT_TRUE(ahead->made_ahead() && ahead->prepared());
        Simulation taken(bunny.mesh, one, nullptr, ahead.get());
        EXPECT_EQ(taken.from_snapshot(), Simulation::FromSnapshot::Setup);
        EXPECT_TRUE(taken.setup_made_ahead());
        EXPECT_GT(taken.setup_seconds().ahead, 0.0);
        expect_same_setup(fresh, taken);
        EXPECT_EQ(*taken.corner_normals(), *fresh.corner_normals());
        EXPECT_EQ(taken.setup_snapshot(), fresh.setup_snapshot());
        expect_same_iterations(fresh, taken);
        // two surfaces: only the surfels are taken, the rest built for that binding
        Config two = bunny_config(threads);
        two.triangle_surface = bunny.binding;
        SurfelSample sample2(bunny.mesh, size_t(two.surfels), two.seed, threads);
        auto ahead2 = SetupSnapshot::make_ahead(bunny.mesh, sample2, threads);
        Simulation surfels_only(bunny.mesh, two, nullptr, ahead2.get());
        EXPECT_EQ(surfels_only.from_snapshot(), Simulation::FromSnapshot::Surfels);
        EXPECT_TRUE(surfels_only.setup_made_ahead());
        Simulation plain(bunny.mesh, two);
        expect_same_setup(surfels_only, plain);
        EXPECT_EQ(*surfels_only.corner_normals(), *plain.corner_normals());
    }
    // a sample without surfels (another mesh's count of zero) is refused
    SurfelSample empty(bunny.mesh, 0, 1, 1);
    EXPECT_NE(expect_error([&] { SetupSnapshot::make_ahead(bunny.mesh, empty, 1); }).find("no surfels"),
              std::string::npos);
}

TEST(SetupSnapshot, IsTakenOnlyForTheSameMeshCountSeedAndBinding) {
    const Bunny bunny;
    Config c = bunny_config(2);
    c.triangle_surface = bunny.binding;
    Simulation fresh(bunny.mesh, c);
    const std::vector<uint8_t> bytes = fresh.setup_snapshot();

    Config other_seed = c, other_count = c, other_binding = c;
    other_seed.seed = 12;
    other_count.surfels = 5999;
    other_binding.triangle_surface[0] = 1 - other_binding.triangle_surface[0];
    Mesh moved = bunny.mesh;
    moved.vertices[3 * size_t(moved.triangles[0]) + 1] += 1e-4f;   // inside the bounds
    struct Case {
        const char* what;
        const Mesh& mesh;
        const Config& config;
    };
    for (const Case& k : {Case{"seed", bunny.mesh, other_seed}, Case{"count", bunny.mesh, other_count},
                          Case{"binding", bunny.mesh, other_binding}, Case{"vertex", moved, c}}) {
        SetupSnapshot snap(bytes.data(), bytes.size());
        snap.prepare(bunny.mesh, 2);   // for the snapshot's own binding: of no use to another
        Simulation sim(k.mesh, k.config, nullptr, &snap);
        // another binding samples the same surfels: those are taken, the rest is built
        const bool binding = std::string(k.what) == "binding";
        EXPECT_EQ(sim.from_snapshot(),
                  binding ? Simulation::FromSnapshot::Surfels : Simulation::FromSnapshot::Nothing) << k.what;
        EXPECT_EQ(snap.taken(), binding) << k.what;
        Simulation plain(k.mesh, k.config);
        expect_same_setup(sim, plain);
        EXPECT_EQ(*sim.corner_normals(), *plain.corner_normals());
    }
}

TEST(SetupSnapshot, DamagedBytesAreRefusedNeverRead) {
    const Bunny bunny;
    Config c = bunny_config(2);
    c.surfels = 2000;
    c.triangle_surface = bunny.binding;
    const Simulation fresh(bunny.mesh, c);
    const std::vector<uint8_t> bytes = fresh.setup_snapshot();
    ASSERT_NO_THROW(SetupSnapshot(bytes.data(), bytes.size()));
    // prepared for another mesh: nothing is built (and the snapshot stays whole)
    SetupSnapshot whole(bytes.data(), bytes.size());
    whole.prepare(gamma_test::icosphere(2), 2);
    EXPECT_FALSE(whole.prepared());
    EXPECT_FALSE(whole.taken());
    // cut anywhere: refused
    for (size_t cut : {size_t(0), size_t(7), size_t(40), size_t(41), bytes.size() / 3, bytes.size() / 2,
                       bytes.size() - 8, bytes.size() - 1}) {
        const std::string e = expect_error([&] { SetupSnapshot s(bytes.data(), cut); });
        EXPECT_NE(e.find("setup snapshot"), std::string::npos) << cut << ": " << e;
    }
    // a byte more: refused
    std::vector<uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_NE(expect_error([&] { SetupSnapshot s(longer.data(), longer.size()); }).find("bytes follow"),
              std::string::npos);
    // another magic, another format: refused
    std::vector<uint8_t> other = bytes;
    other[0] ^= 1;
    EXPECT_NE(expect_error([&] { SetupSnapshot s(other.data(), other.size()); }).find("not a setup snapshot"),
              std::string::npos);
    other = bytes;
    other[8] ^= 1;
    EXPECT_NE(expect_error([&] { SetupSnapshot s(other.data(), other.size()); }).find("another format"),
              std::string::npos);
    // A surfel's triangle and a splat source out of range: each refused
    // (the checks that keep the simulation's reads in bounds).
    auto refused_after = [&](const std::function<void(std::vector<uint8_t>&)>& damage, const char* what) {
        std::vector<uint8_t> d = bytes;
        damage(d);
        const std::string e = expect_error([&] { SetupSnapshot s(d.data(), d.size()); });
        EXPECT_NE(e.find(what), std::string::npos) << e;
    };
    // the sections' places from the layout (setup_snapshot.cpp)
    const size_t n = size_t(c.surfels);
    auto padded = [](size_t b) { return (b + 7) / 8 * 8; };
    size_t at = 40;                                           // header
    at += 16 + padded(24);                                    // lo, hi
    at += 16 + padded(4 * bunny.mesh.vertices.size());
    at += 16 + padded(4 * bunny.mesh.triangles.size());
    at += 16 + padded(4 * bunny.binding.size());
    at += 2 * (16 + padded(12 * n));                          // positions, normals
    const size_t triangle_section = at + 16;
    refused_after([&](std::vector<uint8_t>& d) {
        const int32_t bad = int32_t(bunny.mesh.num_triangles());
        std::memcpy(&d[triangle_section], &bad, 4);
    }, "surfel triangles");
    at += 16 + padded(4 * n) + 16 + 8;                        // triangles, r_max
    at += 16 + padded(4 * (n + 1));                           // splat offsets
    const size_t source_section = at + 16;
    refused_after([&](std::vector<uint8_t>& d) {
        const uint32_t bad = uint32_t(n);
        std::memcpy(&d[source_section], &bad, 4);
    }, "splat kernel sources");
}

namespace {

// Where section `tag` (setup_snapshot.cpp's order, from 1) holds its
// elements in `bytes`, and how many it holds.
std::pair<size_t, size_t> section_of(const std::vector<uint8_t>& bytes, uint32_t tag) {
    size_t at = 40;   // the header
    for (;;) {
        uint32_t t = 0, size = 0;
        uint64_t count = 0;
        std::memcpy(&t, &bytes[at], 4);
        std::memcpy(&size, &bytes[at + 4], 4);
        std::memcpy(&count, &bytes[at + 8], 8);
        if (t == tag) return {at + 16, size_t(count)};
        at += 16 + (size_t(size) * count + 7) / 8 * 8;
    }
}

template <typename T>
void put(std::vector<uint8_t>& bytes, size_t at, T value) {
    std::memcpy(&bytes[at], &value, sizeof value);
}
template <typename T>
T get(const std::vector<uint8_t>& bytes, size_t at) {
    T value;
    std::memcpy(&value, &bytes[at], sizeof value);
    return value;
}

}  // namespace

// Every index of the triangle lookup a damaged snapshot could carry out of
// range, or two heads sharing one block of entries: refused by the parse,
// never left for the scan to read.
TEST(SetupSnapshot, ALookupIndexOutOfRangeIsRefused) {
    // a floor of two large triangles (cut into cells) and a sphere on it
    gamma_test::Builder b;
    gamma_test::floor_quad(b, -3, 3, -3, 3);
    b.add(gamma_test::icosphere(2, 0.5f), {0, 0.5f, 0});
    const Mesh m = b.mesh();
    Config c;
    c.surfels = 3000;
    c.threads = 2;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 0}};
    const Simulation fresh(m, c);
    const std::vector<uint8_t> bytes = fresh.setup_snapshot();
    ASSERT_NO_THROW(SetupSnapshot(bytes.data(), bytes.size()));
    const auto [grids, n_grids] = section_of(bytes, 14);
    const auto [cells, n_cells] = section_of(bytes, 15);
    const auto [packed, n_packed] = section_of(bytes, 16);
    const auto [heads, n_heads] = section_of(bytes, 17);
    const auto [cell_at, n_cell_at] = section_of(bytes, 18);
    ASSERT_GT(n_grids, 0u);   // the floor is cut into cells
    ASSERT_EQ(n_heads, m.num_triangles());
    ASSERT_EQ(n_cell_at, n_cells);
    constexpr size_t kHead = 128, kCount = 16, kMore = 20, kFirstId = 24 + 16, kEntry = 20;
    // the heads of each kind: with more entries than inline, with inline ones only, cut into cells
    size_t long_head = SIZE_MAX, short_head = SIZE_MAX, grid_head = SIZE_MAX;
    for (size_t t = 0; t < n_heads; ++t) {
        const uint32_t count = get<uint32_t>(bytes, heads + t * kHead + kCount);
        if (count > SceneIndex::kInlineCandidates && long_head == SIZE_MAX) long_head = t;
        if (count > 0 && count <= SceneIndex::kInlineCandidates && short_head == SIZE_MAX) short_head = t;
        if (count == 0 && (get<uint32_t>(bytes, heads + t * kHead + kMore) & SceneIndex::kGridBit)) grid_head = t;
    }
    ASSERT_NE(long_head, SIZE_MAX);
    ASSERT_NE(short_head, SIZE_MAX);
    ASSERT_NE(grid_head, SIZE_MAX);
    size_t used_cell = SIZE_MAX;
    for (size_t k = 0; k < n_cell_at && used_cell == SIZE_MAX; ++k)
        if (get<uint32_t>(bytes, cell_at + 4 * k) != SceneIndex::kNoBlock) used_cell = k;
    ASSERT_NE(used_cell, SIZE_MAX);
    const uint32_t n = uint32_t(c.surfels);
    struct Damage {
        const char* what;
        size_t at;
        uint32_t value;
    };
    const size_t lh = heads + long_head * kHead, sh = heads + short_head * kHead, gh = heads + grid_head * kHead;
    const uint32_t long_more = get<uint32_t>(bytes, lh + kMore);
    const std::vector<Damage> damages = {
        {"a head's entries past the end", lh + kMore, uint32_t(n_packed)},
        {"a head's count past the end", lh + kCount, 0x7fffffffu},
        {"a head's inline id", sh + kFirstId, n},
        {"a head's grid", gh + kMore, SceneIndex::kGridBit | uint32_t(n_grids)},
        {"a head's block that is no grid", gh + kMore, 5u},
        {"a grid's side", grids + 36, 0u},
        {"a grid's side above the largest", grids + 36, SceneIndex::kMaxGridSide + 1},
        {"a grid's first cell", grids + 40, uint32_t(n_cells)},
        {"a cell's block", cell_at + 4 * used_cell, uint32_t(n_packed)},
        {"a candidate's id", packed + (long_more + 0) * kEntry + 16, n},
        {"a cell's count", packed + get<uint32_t>(bytes, cell_at + 4 * used_cell) * kEntry + 16, 0x7fffffffu},
        {"a head sharing a cell's block", lh + kMore, get<uint32_t>(bytes, cell_at + 4 * used_cell) + 1},
    };
    for (const Damage& d : damages) {
        std::vector<uint8_t> damaged = bytes;
        put(damaged, d.at, d.value);
        const std::string e = expect_error([&] { SetupSnapshot s(damaged.data(), damaged.size()); });
        EXPECT_NE(e.find("setup snapshot: inconsistent lookup"), std::string::npos) << d.what << ": " << e;
    }
}
