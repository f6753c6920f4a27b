// The setup cache's files: names, reading, and gammac run's read-ahead (see
// setup_cache.h).
#include "gamma/setup_cache.h"

#include <link.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <vector>

#include <tbb/task_group.h>

#include "gamma/error.h"
#include "gamma/shading.h"
#include "gamma/threads.h"

namespace gammart {
namespace {

std::string hex(const unsigned char* bytes, size_t n) {
    static const char digits[] = "0123456789abcdef";
    std::string out;
    for (size_t k = 0; k < n; ++k) {
        out += digits[bytes[k] >> 4];
        out += digits[bytes[k] & 15];
    }
    return out;
}

// The loaded object holding `address`: its build ID (empty if it has none)
// and its file's path (empty for the main program).
struct OwnObject {
    uintptr_t address = 0;
    bool found = false;
    std::string build_id, path;
};

int find_own_object(dl_phdr_info* info, size_t, void* data) {
    OwnObject& own = *static_cast<OwnObject*>(data);
    bool holds = false;
    for (int i = 0; i < info->dlpi_phnum && !holds; ++i) {
        const ElfW(Phdr)& ph = info->dlpi_phdr[i];
        const uintptr_t start = info->dlpi_addr + ph.p_vaddr;
        holds = ph.p_type == PT_LOAD && own.address >= start && own.address - start < ph.p_memsz;
    }
    if (!holds) return 0;
    own.found = true;
    own.path = info->dlpi_name ? info->dlpi_name : "";
    for (int i = 0; i < info->dlpi_phnum; ++i) {
        const ElfW(Phdr)& ph = info->dlpi_phdr[i];
        if (ph.p_type != PT_NOTE) continue;
        // a note: header, name and description, each padded to the segment's alignment
        const size_t align = ph.p_align == 8 ? 8 : 4;
        auto padded = [align](size_t n) { return (n + align - 1) / align * align; };
        const char* p = reinterpret_cast<const char*>(info->dlpi_addr + ph.p_vaddr);
        size_t left = ph.p_memsz;
        while (left >= sizeof(ElfW(Nhdr))) {
            ElfW(Nhdr) note;
            std::memcpy(&note, p, sizeof note);
            const size_t name = padded(note.n_namesz), desc = padded(note.n_descsz);
            if (name > left - sizeof note || desc > left - sizeof note - name) break;
            const char* name_at = p + sizeof note;
            if (note.n_type == NT_GNU_BUILD_ID && note.n_namesz == 4 && std::memcmp(name_at, "GNU", 4) == 0 &&
                note.n_descsz > 0) {
                own.build_id = hex(reinterpret_cast<const unsigned char*>(name_at + name), note.n_descsz);
                return 1;
            }
            p += sizeof note + name + desc;
            left -= sizeof note + name + desc;
        }
    }
    return 1;
}

// Without a build ID: the module's file, summed (a build rewrites it).
std::string file_build(const std::string& path) {
    std::ifstream in(path.empty() ? "/proc/self/exe" : path, std::ios::binary);
    if (!in) return "";
    uLong crc = crc32(0L, Z_NULL, 0), adler = adler32(0L, Z_NULL, 0);
    uint64_t size = 0;
    std::vector<char> block(size_t(1) << 20);
    while (in.read(block.data(), std::streamsize(block.size())) || in.gcount() > 0) {
        const auto n = uInt(in.gcount());
        crc = crc32(crc, reinterpret_cast<const Bytef*>(block.data()), n);
        adler = adler32(adler, reinterpret_cast<const Bytef*>(block.data()), n);
        size += n;
    }
    if (in.bad()) return "";
    char text[64];
    std::snprintf(text, sizeof text, "file-%llx-%08lx-%08lx", static_cast<unsigned long long>(size),
                  static_cast<unsigned long>(crc), static_cast<unsigned long>(adler));
    return text;
}

std::string find_runtime_build() {
    OwnObject own;
    own.address = reinterpret_cast<uintptr_t>(&find_own_object);
    dl_iterate_phdr(find_own_object, &own);
    if (!own.found) return "";
    return own.build_id.empty() ? file_build(own.path) : own.build_id;
}

bool signature_of(const std::string& path, FileSignature& out) {
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
    out.size = int64_t(st.st_size);
    out.mtime_ns = int64_t(st.st_mtim.tv_sec) * 1000000000 + int64_t(st.st_mtim.tv_nsec);
    out.inode = uint64_t(st.st_ino);
    out.device = uint64_t(st.st_dev);
    return true;
}

}  // namespace

const std::string& runtime_build() {
    static const std::string build = find_runtime_build();
    return build;
}

std::string setup_cache_name(const Mesh& mesh, size_t surfels, uint64_t seed) {
    const std::string& build = runtime_build();
    if (build.empty()) return "";
    return "setup-" + build + "-" + mesh_fingerprint(mesh) + "-" + std::to_string(surfels) + "-" +
           std::to_string(seed) + ".bin";
}

namespace {

// The cache file for this mesh, count and seed in `folder` if there is one
// (a regular file), else "".
std::string cached_setup_path(const std::string& folder, const Mesh& mesh, size_t surfels, uint64_t seed) {
    const std::string name = setup_cache_name(mesh, surfels, seed);
    if (folder.empty() || name.empty()) return "";
    const std::string path = folder + "/" + name;
    struct stat st {};
    return ::stat(path.c_str(), &st) == 0 && S_ISREG(st.st_mode) ? path : "";
}

// load_cached_setup's reading of `path` (cached_setup_path's).
std::unique_ptr<SetupSnapshot> read_cached_setup(const std::string& path) {
    try {
        auto snapshot = std::make_unique<SetupSnapshot>(SetupSnapshot::read(path));
        ::utimes(path.c_str(), nullptr);   // recently used: trimmed last (a failure only costs order)
        return snapshot;
    } catch (const Error&) {
        ::unlink(path.c_str());            // damaged, cut short, not a snapshot: this run's replaces it
    } catch (const std::exception&) {      // cannot be read (another user's file): left alone
    }
    return nullptr;
}

}  // namespace

std::unique_ptr<SetupSnapshot> load_cached_setup(const std::string& folder, const Mesh& mesh, size_t surfels,
                                                 uint64_t seed) {
    try {
        const std::string path = cached_setup_path(folder, mesh, surfels, seed);
        return path.empty() ? nullptr : read_cached_setup(path);
    } catch (const std::exception&) {
        return nullptr;
    }
}

MeshAhead read_mesh_ahead(const std::string& path, const std::string& cache_folder, size_t surfels,
                          uint64_t seed, int threads) {
    MeshAhead ahead;
    try {
        FileSignature before, after;
        // not a regular file (a FIFO would block the read): read, and reported, later
        if (!signature_of(path, before)) return ahead;
        auto mesh = std::make_unique<Mesh>(Mesh::load(path));
        if (!signature_of(path, after) || !(after == before)) return ahead;
        const std::string cached = surfels > 0 ? cached_setup_path(cache_folder, *mesh, surfels, seed) : "";
        if (!cached.empty()) {
            // The renders' corner normals need the mesh only: computed beside the
            // file's reading, which is one core's work (their result never
            // depends on the scheduling).
            std::vector<float> normals;
            run_with_threads(threads, [&] {
                tbb::task_group beside;
                beside.run([&] { normals = corner_normals(*mesh, {}, kDefaultCreaseDeg); });
                try {
                    ahead.setup = read_cached_setup(cached);
                } catch (...) {
                    beside.wait();
                    throw;
                }
                beside.wait();
            });
            if (ahead.setup) ahead.setup->prepare(*mesh, threads, std::move(normals));
        }
        ahead.mesh = std::move(mesh);
        ahead.signature = before;
    } catch (const std::exception&) {
        ahead = MeshAhead{};
    }
    return ahead;
}

}  // namespace gammart
