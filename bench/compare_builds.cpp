// Old-vs-new timing of two (or more) builds of libhaptic_hand, interleaved step by step in one
// process on the same mesh and scenario, so that both see the same machine load (the machine
// this project runs on is shared and often busy: compare ratios, quote absolute numbers with
// the load average). The scenario is bench_step.py's: default parameters, handle radius 30 mm,
// the device frame held 1 cm from the handle's rest centre of mass, gravity on.
//
//   .venv/bin/python bench/bench_step.py --sizes 1700,20000 --export-meshes build/bench/meshes
//   g++ -O2 -std=c++17 -Inative/include bench/compare_builds.cpp -o build/bench/compare_builds -ldl
//   build/bench/compare_builds build/bench/meshes/hand_20000.bin 40 3
//       /tmp/old/libhaptic_hand.so:2:old build/solver/libhaptic_hand.so:2:new   (one line)
//
// Each variant is LIB:SOLVER[:NAME] (SOLVER: 0 Cholesky, 1 CG, 2 reused Cholesky). Prints per
// variant the mean, median, min and max step time, the mean assembly and deformable-solve
// times, CG iterations per step, the largest CG residual, and how far each run's node positions
// ended from the first variant's (relative to the largest displacement).
#include <dlfcn.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "haptic_hand.h"

namespace {
struct Variant {
    std::string name;
    void* lib = nullptr;
    int solver = 0;
    decltype(&hh_default_params) default_params = nullptr;
    decltype(&hh_model_create) model_create = nullptr;
    decltype(&hh_data_create) data_create = nullptr;
    decltype(&hh_step) step = nullptr;
    decltype(&hh_set_device) set_device = nullptr;
    decltype(&hh_model_info_get) info = nullptr;
    decltype(&hh_get_state) get_state = nullptr;
    decltype(&hh_last_error) last_error = nullptr;
    hh_model* model = nullptr;
    hh_data* data = nullptr;
    std::vector<hh_step_stats> stats;
};
template <class F>
void bind(void* lib, F& f, const char* name) {
    f = reinterpret_cast<F>(dlsym(lib, name));
    if (!f) {
        std::fprintf(stderr, "missing symbol %s\n", name);
        std::exit(1);
    }
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 5) {
        std::fprintf(stderr, "usage: %s MESH.bin STEPS WARMUP LIB:SOLVER[:NAME] ...\n", argv[0]);
        return 2;
    }
    FILE* f = std::fopen(argv[1], "rb");
    if (!f) {
        std::perror(argv[1]);
        return 1;
    }
    int nn = 0, nt = 0;
    double seed[3];
    bool ok = std::fread(&nn, 4, 1, f) == 1 && std::fread(&nt, 4, 1, f) == 1 && std::fread(seed, 8, 3, f) == 3;
    std::vector<double> nodes(3 * static_cast<size_t>(nn));
    std::vector<int> tets(4 * static_cast<size_t>(nt));
    ok = ok && std::fread(nodes.data(), 8, nodes.size(), f) == nodes.size() && std::fread(tets.data(), 4, tets.size(), f) == tets.size();
    std::fclose(f);
    if (!ok) {
        std::fprintf(stderr, "%s: not a mesh written by bench_step.py --export-meshes\n", argv[1]);
        return 1;
    }
    const int steps = std::atoi(argv[2]), warmup = std::atoi(argv[3]);
    std::vector<Variant> variants;
    for (int i = 4; i < argc; ++i) {
        const std::string spec = argv[i];
        const size_t c1 = spec.find(':'), c2 = spec.find(':', c1 + 1);
        if (c1 == std::string::npos) {
            std::fprintf(stderr, "variant %s: expected LIB:SOLVER[:NAME]\n", argv[i]);
            return 2;
        }
        Variant v;
        v.solver = std::atoi(spec.substr(c1 + 1, c2 - c1 - 1).c_str());
        v.name = c2 == std::string::npos ? spec : spec.substr(c2 + 1);
        v.lib = dlopen(spec.substr(0, c1).c_str(), RTLD_NOW | RTLD_LOCAL);
        if (!v.lib) {
            std::fprintf(stderr, "%s\n", dlerror());
            return 1;
        }
        bind(v.lib, v.default_params, "hh_default_params");
        bind(v.lib, v.model_create, "hh_model_create");
        bind(v.lib, v.data_create, "hh_data_create");
        bind(v.lib, v.step, "hh_step");
        bind(v.lib, v.set_device, "hh_set_device");
        bind(v.lib, v.info, "hh_model_info_get");
        bind(v.lib, v.get_state, "hh_get_state");
        bind(v.lib, v.last_error, "hh_last_error");
        hh_params p;
        v.default_params(&p);
        for (int k = 0; k < 3; ++k) p.palm_seed[k] = seed[k];
        p.handle_radius = 0.03;
        p.solver = v.solver;
        p.cg_tolerance = 1e-6;
        if (v.model_create(nodes.data(), nn, tets.data(), nt, &p, &v.model) || v.data_create(v.model, &v.data)) {
            std::fprintf(stderr, "%s: %s\n", v.name.c_str(), v.last_error());
            return 1;
        }
        hh_model_info info;
        v.info(v.model, &info);
        const double pos[3] = {info.handle_com[0] + 0.01, info.handle_com[1], info.handle_com[2]}, q[4] = {0, 0, 0, 1}, zero[3] = {0, 0, 0};
        v.set_device(v.data, 1, pos, q, zero, zero);
        variants.push_back(v);
    }
    for (int s = 0; s < warmup + steps; ++s)
        for (Variant& v : variants) {
            hh_step_stats st;
            if (v.step(v.model, v.data, &st)) {
                std::fprintf(stderr, "%s: %s\n", v.name.c_str(), v.last_error());
                return 1;
            }
            if (s >= warmup) v.stats.push_back(st);
        }
    double load[3] = {0, 0, 0};
    if (FILE* l = std::fopen("/proc/loadavg", "r")) {
        if (std::fscanf(l, "%lf %lf %lf", &load[0], &load[1], &load[2]) != 3) load[0] = load[1] = load[2] = -1;
        std::fclose(l);
    }
    std::printf("%d nodes, %d tets; %d steps after %d warm-up, interleaved; load average %.2f %.2f %.2f\n", nn, nt, steps,
                warmup, load[0], load[1], load[2]);
    std::printf("%-14s %8s %8s %8s %8s %8s %8s %7s %9s %9s\n", "variant", "mean ms", "median", "min", "max", "asm", "deform",
                "it/step", "max res", "|dx| rel");
    std::vector<double> x_first;
    for (Variant& v : variants) {
        std::vector<double> t;
        double assembly = 0, deformable = 0, iterations = 0, residual = 0;
        for (const hh_step_stats& st : v.stats) {
            t.push_back(st.t_total);
            assembly += st.t_assembly;
            deformable += st.t_deformable;
            iterations += st.cg_iterations;
            residual = std::max(residual, st.max_residual);
        }
        const double n = static_cast<double>(t.size());
        double mean = 0;
        for (double x : t) mean += x;
        mean /= n;
        std::sort(t.begin(), t.end());
        std::vector<double> x(3 * static_cast<size_t>(nn)), vel(x.size());
        double hp[3], hq[4], hv[3], hw[3];
        v.get_state(v.model, v.data, x.data(), vel.data(), nn, hp, hq, hv, hw);
        std::string diff = "-";
        if (x_first.empty()) {
            x_first = x;
        } else {
            double d = 0, moved = 0;
            for (size_t i = 0; i < x.size(); ++i) {
                d = std::max(d, std::abs(x[i] - x_first[i]));
                moved = std::max(moved, std::abs(x_first[i] - nodes[i]));
            }
            char buf[32];
            std::snprintf(buf, sizeof buf, "%.1e", d / std::max(moved, 1e-300));
            diff = buf;
        }
        std::printf("%-14s %8.2f %8.2f %8.2f %8.2f %8.2f %8.2f %7.1f %9.1e %9s\n", v.name.c_str(), 1e3 * mean, 1e3 * t[t.size() / 2],
                    1e3 * t.front(), 1e3 * t.back(), 1e3 * assembly / n, 1e3 * deformable / n, iterations / n, residual, diff.c_str());
    }
    return 0;
}
