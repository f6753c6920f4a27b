// The setup cache's files (SPEC §16.1, compiler/gamma/driver/setup_cache.py)
// as the runtime sees them: their names, their reading (refusing what cannot
// be used), and `gammac run`'s read-ahead of its mesh and cached setup as one
// call that needs no Python.
//
// gammac reads its mesh, and the setup the cache keeps for it, on a thread
// while its main thread imports the compiler.  Done as several calls from
// Python (read the mesh, hash it, name the file, read it, prepare it), that
// thread had to take the GIL between them, and often waited for it while the
// main thread imported; `read_mesh_ahead` is the whole chain in C++, so
// the thread takes the GIL only to start and to hand its result back.  The
// cache file's name is therefore made here, and setup_cache.py asks for it.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "gamma/mesh.h"
#include "gamma/setup_snapshot.h"

namespace gammart {

// The runtime build: the linker's build ID (.note.gnu.build-id, a hash of
// the linked code) of the module this code is linked into, as hex; without
// one, "file-" and the size, CRC-32 and Adler-32 of the module's file.  Two
// builds whose sampling or lookup differ have different code, so different
// names (the version string stays the same across them).  Empty if neither
// can be found: then nothing is cached.
const std::string& runtime_build();

// The setup cache's file name for a setup of `surfels` surfels on `mesh`
// with `seed`: "setup-{build}-{mesh fingerprint}-{surfels}-{seed}.bin".
// Empty when the build is unknown.
std::string setup_cache_name(const Mesh& mesh, size_t surfels, uint64_t seed);

// The snapshot the setup cache in `folder` keeps for this mesh, count and
// seed, or null: none kept (or the cache's name for it is not a regular
// file), or a file that cannot be read (another user's: left alone), or one
// that is damaged, cut short or not a snapshot of this build (then removed,
// so this run's setup replaces it).  A file taken is marked recently used
// (its modification time set to now: the cache's trim removes the least
// recently used first).  Never throws.
std::unique_ptr<SetupSnapshot> load_cached_setup(const std::string& folder, const Mesh& mesh, size_t surfels,
                                                 uint64_t seed);

// What identifies a file's version: as Python's os.stat gives them, so that
// the driver compares them with its own stat later (prefetch.py).
struct FileSignature {
    int64_t size = 0, mtime_ns = 0;
    uint64_t inode = 0, device = 0;
    bool operator==(const FileSignature& o) const {
        return size == o.size && mtime_ns == o.mtime_ns && inode == o.inode && device == o.device;
    }
};

// gammac run's read-ahead (prefetch.py): the mesh file `path` read, and,
// when `cache_folder` is not empty and `surfels` > 0, the setup the cache
// keeps for it, `surfels` and `seed` loaded (load_cached_setup) and
// prepared on `threads` threads (SetupSnapshot::prepare).
struct MeshAhead {
    // Null when the file is not a regular file, cannot be read or parsed, or
    // changed while it was read: the driver reads it again where it always
    // did and reports the error there.
    std::unique_ptr<Mesh> mesh;
    FileSignature signature;   // the file's, before it was read (and unchanged after)
    // Null when none is kept (or it could not be used): the setup samples.
    std::unique_ptr<SetupSnapshot> setup;
};
// Never throws.
MeshAhead read_mesh_ahead(const std::string& path, const std::string& cache_folder, size_t surfels,
                          uint64_t seed, int threads);

}  // namespace gammart
