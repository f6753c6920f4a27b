// The configuration of a run, as the Python driver (or a C++ test) fills it:
// surfels, seed, threads, surfaces and their initial rows, ton types,
// sources and the addresses of the compiled kernels.
#pragma once
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "gamma/mesh.h"
#include "gamma_abi.h"

namespace gammart {

struct TonType {
    float ks = 0, kp = 0, kf = 0;
    std::vector<float> initial_carry;
    float bounce_distance = 1;  // scene units: range of a 45-degree launch on flat ground
    float flow_step = 1;        // scene units: length of one flow step
    float drip_angle_deg = 10;  // flow clings to faces turned down at most this far past vertical
};

struct Source {
    std::string kind;  // point | spot | rect | disk | directional | sphere | hemisphere | surface
    int ton_type = 0;
    int64_t count = 0;
    std::array<float, 3> position{0, 0, 0};
    std::array<float, 3> direction{0, -1, 0};
    float angle_deg = 0;              // spot: cone half-angle, (0, 180]
    float falloff = 0;                // spot: cos^n exponent, >= 0
    std::array<float, 2> size{0, 0};  // rect: width (along u), height (along v)
    float radius = 0;                 // disk
    std::string emission = "parallel";  // rect/disk: parallel | uniform | cosine
    int first_iteration = 1;          // active in first..last (inclusive)
    int last_iteration = 0;           // 0 = no end
    float strength = 0;               // > 0: gamma-tons weigh strength * surfels / count (SPEC 13.2); 0: weight 1
    int surface = -1;                 // surface: the surface whose surfels emit
    bool along_normal = false;        // surface: each surfel's normal is the axis (else `direction`)
    uint64_t weight_kernel = 0;       // surface: GammaUpdateKernel storing the weight at row slot W (0: 1)
};

struct TransportEntry {
    int event = 0, ton_type = 0, surface = 0;
    uint64_t address = 0;
    bool writes_surface = false;
};

struct UpdateEntry {
    int surface = 0;
    uint64_t address = 0;
};

struct AppearanceEntry {
    int surface = 0;
    uint64_t address = 0;  // GammaAppearanceKernel; 0 = none (neutral albedo)
    bool displaces = false;  // assigns `displacement`: the renders bend the normal by its slope
};

// A surface's shape follows a property: each iteration the surface moves
// along its outward normal by metres_per_unit x the change of row column
// `column` during the iteration (SPEC §19, "Shape change").
struct ShapeRate {
    int surface = 0;
    int column = 0;              // row index (>= GAMMA_ROW_HEADER)
    float metres_per_unit = 0;
};

// A property whose pick-up is accounted (mass books): its row column on each
// surface and, per ton type, the index of the carried attribute of the same
// name (-1 where the surface lacks it / the ton type does not carry it).
struct MassProperty {
    std::vector<int> column;     // [surface]
    std::vector<int> carry;      // [ton type]
};

struct Config {
    int64_t surfels = 100000;
    uint64_t seed = 1;
    int threads = 1;             // <= 0: all hardware threads
    int max_interactions = 100;
    // Chunks of kChunkSize gamma-tons traced before their deposit logs are
    // summed (tracer.h): bounds the memory of a pass; never changes results.
    // 0: the default, max(64, 8 x threads).
    int64_t trace_batch_chunks = 0;
    // Interactions of a group of gamma-tons' paths the tracer stores before
    // it finishes the group's lives one by one (tracer.cpp): bounds a
    // thread's memory; never changes results.  0: the default, 65536.  For
    // the tests; not among the options a user sets.
    int64_t trace_step_budget = 0;
    int row_width = GAMMA_ROW_HEADER;
    std::array<float, 3> down{0, -1, 0};           // gravity; normalised by the runtime
    std::vector<std::vector<float>> surface_rows;  // initial row per surface id
    std::vector<int32_t> triangle_surface;         // per triangle; empty -> all 0
    std::vector<TonType> ton_types;
    std::vector<Source> sources;
    std::vector<TransportEntry> transports;
    std::vector<UpdateEntry> updates;
    std::vector<AppearanceEntry> appearances;
    std::vector<ShapeRate> shape_rates;        // empty: the shape never changes
    float retile_edge_factor = 2.0f;           // target edge length = factor x surfel spacing sqrt(A/N)
    int retile_iterations = 3;                 // CGAL remeshing rounds per shape step
    float max_step_factor = 0.5f;              // |displacement| per iteration <= factor x target edge length
    int displacement_rings = 2;                // vertex displacements averaged over this many rings (SPEC §13.12)
    std::vector<MassProperty> mass_properties;
    // Per-surfel measures computed when the surfels are placed (SPEC §12):
    // only those some kernel reads, as they cost setup time.
    bool measure_accessibility = false, measure_curvature = false, measure_uv = false;
    // Whatever owns the machine code at the kernel addresses above (the host's
    // JIT): a simulation keeps it alive for as long as it keeps this config,
    // so dropping the host's handle early cannot leave dangling addresses.
    std::shared_ptr<const void> code_owner;

    int add_ton_type(float ks, float kp, float kf, std::vector<float> carry, float bounce_distance = 1.0f,
                     float flow_step = 1.0f, float drip_angle_deg = 10.0f) {
        ton_types.push_back({ks, kp, kf, std::move(carry), bounce_distance, flow_step, drip_angle_deg});
        return int(ton_types.size()) - 1;
    }
    int add_source(Source s) {
        sources.push_back(std::move(s));
        return int(sources.size()) - 1;
    }
    // Short form used by tests: kind, ton type, count, position.
    int add_source(std::string kind, int ton_type, int64_t count, std::array<float, 3> pos = {0, 0, 0}) {
        Source s;
        s.kind = std::move(kind);
        s.ton_type = ton_type;
        s.count = count;
        s.position = pos;
        return add_source(std::move(s));
    }
    void set_transport(int event, int ton_type, int surface, uint64_t address, bool writes) {
        transports.push_back({event, ton_type, surface, address, writes});
    }
    void set_update(int surface, uint64_t address) { updates.push_back({surface, address}); }
    void set_appearance(int surface, uint64_t address, bool displaces = false) {
        appearances.push_back({surface, address, displaces});
    }
    void add_shape_rate(int surface, int column, float metres_per_unit) {
        shape_rates.push_back({surface, column, metres_per_unit});
    }
    void add_mass_property(std::vector<int> column, std::vector<int> carry) {
        mass_properties.push_back({std::move(column), std::move(carry)});
    }
};

// Checks the run-wide settings, the surface rows and the ton types (throws
// gammart::Error with a one-line message) and returns the surface id of every
// kept triangle of `mesh` (triangle_surface may be given per kept or per
// input triangle; empty = all surface 0).  Sources and kernels are checked by
// the parts that use them (sources.h, kernel_table.h).
std::vector<int32_t> validate_config(const Config& c, const Mesh& mesh);

// The longest initial carry of any ton type (at least 1).
size_t max_carry(const Config& c);

}  // namespace gammart
