// A setup snapshot written straight to a file descriptor (the setup cache's
// write, gamma/driver/setup_cache.py) is byte for byte the snapshot made in
// memory, its CRC-32 is zlib's of those bytes, and a failed write throws.
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <cstdio>
#include <stdexcept>
#include <vector>

#include "gamma/simulation.h"
#include "helpers.h"

using namespace gammart;

TEST(SetupSnapshotFd, WrittenToAFileIsTheSnapshotAndItsCrc) {
    const Mesh mesh = gamma_test::icosphere(3);
    Config c;
    c.surfels = 4000;
    c.row_width = 4;
    c.surface_rows = {{0, 0, 0, 1}};
    const Simulation sim(mesh, c);
    const std::vector<uint8_t> bytes = sim.setup_snapshot();
    ASSERT_GT(bytes.size(), size_t(1) << 17);               // larger than the writer's buffer
    std::FILE* f = std::tmpfile();
    ASSERT_NE(f, nullptr);
    const uint32_t crc = sim.write_setup_snapshot(fileno(f));
    std::vector<uint8_t> written(bytes.size() + 1);
    std::rewind(f);
    const size_t got = std::fread(written.data(), 1, written.size(), f);
    std::fclose(f);
    written.resize(got);
    EXPECT_EQ(written, bytes);
    EXPECT_EQ(crc, uint32_t(crc32(crc32(0L, Z_NULL, 0), bytes.data(), uInt(bytes.size()))));
    // a descriptor that cannot be written: an exception, never a partial success
    int ends[2];
    ASSERT_EQ(pipe(ends), 0);
    EXPECT_THROW(sim.write_setup_snapshot(ends[0]), std::runtime_error);   // the read end
    close(ends[0]);
    close(ends[1]);
}
