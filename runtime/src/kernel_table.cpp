// Building and validating the kernel table (see gamma/kernel_table.h).
#include "gamma/kernel_table.h"

#include <string>

#include "gamma/error.h"

namespace gammart {

KernelTable KernelTable::from_config(const Config& c) {
    auto fail = [](const std::string& m) { throw Error(m); };
    const int ntypes = int(c.ton_types.size());
    const int nsurf = int(c.surface_rows.size());
    const int W = c.row_width;
    KernelTable k;
    k.n_types = std::max(ntypes, 1);
    k.n_surfaces = nsurf;
    k.transport.assign(size_t(GAMMA_EVENT_COUNT) * size_t(k.n_types) * size_t(nsurf), TransportSlot{});
    for (const TransportEntry& e : c.transports) {
        if (e.event < 0 || e.event >= GAMMA_EVENT_COUNT)
            fail("config: transport event " + std::to_string(e.event) + " out of range (0.." +
                 std::to_string(GAMMA_EVENT_COUNT - 1) + ")");
        if (e.ton_type < 0 || e.ton_type >= ntypes)
            fail("config: transport ton type index " + std::to_string(e.ton_type) + " out of range (" +
                 std::to_string(ntypes) + " ton types)");
        if (e.surface < 0 || e.surface >= nsurf)
            fail("config: transport surface index " + std::to_string(e.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        TransportSlot& sl =
            k.transport[(size_t(e.event) * size_t(k.n_types) + size_t(e.ton_type)) * size_t(nsurf) + size_t(e.surface)];
        sl.fn = reinterpret_cast<GammaTransportKernel>(static_cast<uintptr_t>(e.address));
        // Only property columns are logged; with none there is nothing to log.
        sl.writes = e.writes_surface && sl.fn && W > GAMMA_ROW_HEADER;
        sl.event = e.event;
        sl.ton_type = e.ton_type;
        sl.surface = e.surface;
    }
    k.update.assign(size_t(nsurf), nullptr);
    for (const UpdateEntry& u : c.updates) {
        if (u.surface < 0 || u.surface >= nsurf)
            fail("config: update surface index " + std::to_string(u.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        k.update[size_t(u.surface)] = reinterpret_cast<GammaUpdateKernel>(static_cast<uintptr_t>(u.address));
    }
    k.appearance.assign(size_t(nsurf), nullptr);
    k.displaces.assign(size_t(nsurf), 0);
    for (const AppearanceEntry& a : c.appearances) {
        if (a.surface < 0 || a.surface >= nsurf)
            fail("config: appearance surface index " + std::to_string(a.surface) + " out of range (" +
                 std::to_string(nsurf) + " surfaces)");
        k.appearance[size_t(a.surface)] =
            reinterpret_cast<GammaAppearanceKernel>(static_cast<uintptr_t>(a.address));
        k.displaces[size_t(a.surface)] = a.displaces && a.address != 0;
    }
    return k;
}

}  // namespace gammart
