// The setup cache's files as the runtime sees them (setup_cache.h): the name
// carries the build, the mesh, the count and the seed; gammac's read-ahead
// gives the mesh Mesh::load gives and the cache's setup, prepared, which a
// Simulation takes whole and which sets it up as from scratch; files it
// cannot use are refused (damaged or cut: removed; not a file: left alone),
// and a mesh file it cannot read gives nothing, never an exception.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gamma/setup_cache.h"
#include "gamma/simulation.h"
#include "setup_helpers.h"

using namespace gammart;
namespace fs = std::filesystem;

namespace {

const std::string kBunny = std::string(GAMMA_SCENES_DIR) + "/stanford-bunny.obj";

Config bunny_config(size_t surfels, uint64_t seed) {
    return gamma_test::deposit_config(int64_t(surfels), seed, 2, 1, {GAMMA_EVENT_SETTLE});
}

// A folder of its own, removed at the end.
struct Folder {
    fs::path path;
    Folder() {
        std::string pattern = (fs::temp_directory_path() / "gamma-setup-cache-XXXXXX").string();
        path = ::mkdtemp(pattern.data());
    }
    ~Folder() { fs::remove_all(path); }
};

void write_bytes(const fs::path& path, const std::vector<uint8_t>& bytes) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

// A cache file as setup_cache.py writes it: the snapshot, its CRC-32, "GMSC".
std::vector<uint8_t> cache_file(std::vector<uint8_t> snapshot) {
    const uint32_t crc = uint32_t(crc32(crc32(0L, Z_NULL, 0), snapshot.data(), uInt(snapshot.size())));
    const uint8_t* c = reinterpret_cast<const uint8_t*>(&crc);
    snapshot.insert(snapshot.end(), c, c + 4);
    for (char m : {'G', 'M', 'S', 'C'}) snapshot.push_back(uint8_t(m));
    return snapshot;
}

}  // namespace

TEST(SetupCache, TheBuildIsTheLinkersBuildId) {
    const std::string& build = runtime_build();
    // --build-id=sha1 (CMakeLists.txt): 20 bytes, as hex
    ASSERT_EQ(build.size(), 40u) << build;
    EXPECT_EQ(build.find_first_not_of("0123456789abcdef"), std::string::npos) << build;
    EXPECT_EQ(&runtime_build(), &build);   // found once
}

TEST(SetupCache, TheNameCarriesTheBuildTheMeshTheCountAndTheSeed) {
    const Mesh mesh = Mesh::load(kBunny);
    const std::string name = setup_cache_name(mesh, 3000, 7);
    EXPECT_EQ(name, "setup-" + runtime_build() + "-" + mesh_fingerprint(mesh) + "-3000-7.bin");
    Mesh moved = mesh;
    moved.vertices[3 * size_t(moved.triangles[0]) + 1] += 1e-4f;
    const std::vector<std::string> names = {name, setup_cache_name(mesh, 3001, 7), setup_cache_name(mesh, 3000, 8),
                                            setup_cache_name(moved, 3000, 7),
                                            setup_cache_name(mesh, 3000, UINT64_C(9223372036854775807))};
    for (size_t a = 0; a < names.size(); ++a)
        for (size_t b = a + 1; b < names.size(); ++b) EXPECT_NE(names[a], names[b]);
    EXPECT_EQ(setup_cache_name(Mesh::load(kBunny), 3000, 7), name);
    EXPECT_LT(names.back().size(), 255u);   // a file name on every file system
}

TEST(SetupCache, TheReadAheadGivesTheMeshAndTheCachedSetupPreparedAndTheSameSetup) {
    const Folder folder;
    const Mesh direct = Mesh::load(kBunny);
    const Config c = bunny_config(3000, 5);
    Simulation fresh(direct, c);
    const fs::path file = folder.path / setup_cache_name(direct, 3000, 5);
    write_bytes(file, cache_file(fresh.setup_snapshot()));
    // an old modification time: a file taken is marked recently used
    const fs::file_time_type old = fs::last_write_time(file) - std::chrono::hours(48);
    fs::last_write_time(file, old);

    MeshAhead ahead = read_mesh_ahead(kBunny, folder.path.string(), 3000, 5, 2);
    ASSERT_TRUE(ahead.mesh && ahead.setup);
    EXPECT_EQ(ahead.mesh->vertices, direct.vertices);
    EXPECT_EQ(ahead.mesh->triangles, direct.triangles);
    EXPECT_EQ(ahead.mesh->lo, direct.lo);
    EXPECT_EQ(ahead.mesh->hi, direct.hi);
    struct stat st {};
    ASSERT_EQ(::stat(kBunny.c_str(), &st), 0);
    EXPECT_EQ(ahead.signature.size, int64_t(st.st_size));
    EXPECT_EQ(ahead.signature.inode, uint64_t(st.st_ino));
    EXPECT_EQ(ahead.signature.mtime_ns, int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec);
    EXPECT_TRUE(ahead.setup->prepared());
    EXPECT_TRUE(fs::exists(file));
    EXPECT_GT(fs::last_write_time(file), old + std::chrono::hours(47));

    Simulation restored(*ahead.mesh, c, nullptr, ahead.setup.get());
    EXPECT_EQ(restored.from_snapshot(), Simulation::FromSnapshot::Setup);
    gamma_test::expect_same_setup(fresh, restored);
    EXPECT_EQ(*restored.corner_normals(), *fresh.corner_normals());
    EXPECT_EQ(restored.setup_snapshot(), fresh.setup_snapshot());
    gamma_test::expect_same_iterations(fresh, restored);

    // the same snapshot as load_cached_setup's, which setup_cache.load uses
    const std::unique_ptr<SetupSnapshot> loaded = load_cached_setup(folder.path.string(), direct, 3000, 5);
    ASSERT_TRUE(loaded);
    EXPECT_FALSE(loaded->prepared());
    Simulation from_loaded(direct, c, nullptr, loaded.get());
    EXPECT_EQ(from_loaded.from_snapshot(), Simulation::FromSnapshot::Setup);
    EXPECT_EQ(from_loaded.setup_snapshot(), restored.setup_snapshot());

    // at one thread (the corner normals computed beside the file's reading, or after it): the same
    MeshAhead one = read_mesh_ahead(kBunny, folder.path.string(), 3000, 5, 1);
    ASSERT_TRUE(one.mesh && one.setup && one.setup->prepared());
    Simulation from_one(*one.mesh, c, nullptr, one.setup.get());
    EXPECT_EQ(from_one.from_snapshot(), Simulation::FromSnapshot::Setup);
    EXPECT_EQ(*from_one.corner_normals(), *fresh.corner_normals());
    EXPECT_EQ(from_one.setup_snapshot(), restored.setup_snapshot());

    // no setup looked for: no folder, no count; none kept for another seed or count
    for (const MeshAhead& other : {read_mesh_ahead(kBunny, "", 3000, 5, 2), read_mesh_ahead(kBunny, folder.path.string(), 0, 5, 2),
                                   read_mesh_ahead(kBunny, folder.path.string(), 3000, 6, 2),
                                   read_mesh_ahead(kBunny, folder.path.string(), 2999, 5, 1)}) {
        ASSERT_TRUE(other.mesh);
        EXPECT_EQ(other.mesh->vertices, direct.vertices);
        EXPECT_FALSE(other.setup);
    }
    EXPECT_TRUE(fs::exists(file));
}

TEST(SetupCache, DamagedOrCutFilesAreRemovedOthersLeftAlone) {
    const Folder folder;
    const Mesh mesh = Mesh::load(kBunny);
    const Simulation fresh(mesh, bunny_config(2000, 3));
    const std::vector<uint8_t> whole = cache_file(fresh.setup_snapshot());
    const fs::path file = folder.path / setup_cache_name(mesh, 2000, 3);

    std::vector<uint8_t> flipped = whole;
    flipped[flipped.size() / 2] ^= 0x40;   // a value inside: only the checksum sees it
    std::vector<uint8_t> foreign = whole;
    foreign[foreign.size() - 1] = 'X';     // not this cache's mark
    const std::vector<std::vector<uint8_t>> refused = {
        flipped, foreign, std::vector<uint8_t>(whole.begin(), whole.begin() + std::ptrdiff_t(whole.size() / 3)),
        std::vector<uint8_t>(whole.begin(), whole.end() - 1), {}, {'x', 'y'}, cache_file(std::vector<uint8_t>(4096, 7))};
    for (size_t k = 0; k < refused.size(); ++k) {
        write_bytes(file, refused[k]);
        const MeshAhead ahead = read_mesh_ahead(kBunny, folder.path.string(), 2000, 3, 2);
        EXPECT_TRUE(ahead.mesh) << k;       // the mesh all the same
        EXPECT_FALSE(ahead.setup) << k;
        EXPECT_FALSE(fs::exists(file)) << k;
        write_bytes(file, refused[k]);
        EXPECT_FALSE(load_cached_setup(folder.path.string(), mesh, 2000, 3)) << k;
        EXPECT_FALSE(fs::exists(file)) << k;
    }
    // not a regular file under the name: not read, left alone
    fs::create_directory(file);
    EXPECT_FALSE(read_mesh_ahead(kBunny, folder.path.string(), 2000, 3, 2).setup);
    EXPECT_TRUE(fs::is_directory(file));
    fs::remove(file);
    ASSERT_EQ(::mkfifo(file.c_str(), 0600), 0);
    EXPECT_FALSE(load_cached_setup(folder.path.string(), mesh, 2000, 3));   // must not block on it
    EXPECT_TRUE(fs::is_fifo(file));
    fs::remove(file);
    // whole again: taken
    write_bytes(file, whole);
    EXPECT_TRUE(read_mesh_ahead(kBunny, folder.path.string(), 2000, 3, 2).setup);
    // a cache folder that is not one: nothing, no exception
    EXPECT_FALSE(read_mesh_ahead(kBunny, (folder.path / "missing" / "deeper").string(), 2000, 3, 2).setup);
    EXPECT_FALSE(read_mesh_ahead(kBunny, file.string(), 2000, 3, 2).setup);
}

TEST(SetupCache, AMeshFileTheReadAheadCannotReadGivesNothing) {
    const Folder folder;
    const fs::path garbage = folder.path / "garbage.obj", pipe = folder.path / "pipe.obj";
    {
        std::ofstream(garbage) << "v 0 0 0\nf 1 2 3 4 5\n";
    }
    ASSERT_EQ(::mkfifo(pipe.c_str(), 0600), 0);
    for (const fs::path& path : {garbage, pipe, folder.path / "missing.obj", folder.path}) {
        const MeshAhead ahead = read_mesh_ahead(path.string(), folder.path.string(), 2000, 3, 2);
        EXPECT_FALSE(ahead.mesh) << path;   // read again, and reported, where it always was
        EXPECT_FALSE(ahead.setup) << path;
    }
}
