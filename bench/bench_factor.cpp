// The per-step factorization of a tet mesh's implicit system At (Eq. 7: lumped masses plus the
// co-rotated stiffness, random element rotations) in the block LDL^T solver's forms, side by
// side in one process: up-looking, supernodal on one thread, and supernodal with its two parts
// on two threads (BlockLDLT::factor_parts), best of N each, with the residual of a solve and
// whether the two-part factor equals the one-thread one bit for bit.
//
//   .venv/bin/python bench/bench_visual.py --export-meshes build/bench/meshes   (or bench_step.py)
//   g++ -O3 -std=c++17 -DNDEBUG -Inative/src -Inative/include -I/usr/include/eigen3 \
//       bench/bench_factor.cpp native/src/*/*.cpp -o build/bench/bench_factor -lpthread -ldl
//   build/bench/bench_factor build/bench/meshes/hand_17000.bin 20
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>
#include <thread>

#include "common/simd.h"
#include "common/worker.h"
#include "fem/corotational.h"
#include "rigid/quaternion.h"
#include "solver/block_ldlt.h"

using namespace hh;

namespace {
SpMat system_matrix(const std::vector<double>& nodes, const std::vector<int>& tets) {
    TetMesh mesh;
    mesh.n_nodes = static_cast<int>(nodes.size() / 3);
    mesh.rest = Eigen::Map<const VecX>(nodes.data(), nodes.size());
    for (size_t e = 0; e < tets.size() / 4; ++e) mesh.tets.emplace_back(tets[4 * e], tets[4 * e + 1], tets[4 * e + 2], tets[4 * e + 3]);
    const CorotationalElements el = precompute_elements(mesh, Material{5e4, 0.3, 1000});
    const StiffnessPattern pat = build_stiffness_pattern(mesh);
    std::mt19937 rng(7);
    std::normal_distribution<double> n(0, 1);
    std::vector<Mat3> rot;
    for (size_t e = 0; e < mesh.tets.size(); ++e) rot.push_back(quat_to_matrix(Vec4(n(rng), n(rng), n(rng), 20 + n(rng)).normalized()));
    SpMat a = pat.matrix;
    const double dt = 1.0 / 30;
    add_warped_stiffness(el, rot, pat, dt * dt, a.valuePtr());
    const VecX m = lumped_masses(mesh, el, 1000);
    for (int i = 0; i < mesh.n_nodes; ++i)
        for (int c = 0; c < 3; ++c) a.coeffRef(3 * i + c, 3 * i + c) += m[i];
    return a;
}

template <class F>
double best_of(int reps, F&& f) {
    double best = 1e300;
    for (int r = 0; r < reps; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        f();
        best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    return best;
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: bench_factor MESH.bin [repetitions]\n");
        return 2;
    }
    std::ifstream f(argv[1], std::ios::binary);
    int nn = 0, nt = 0;
    f.read(reinterpret_cast<char*>(&nn), 4);
    f.read(reinterpret_cast<char*>(&nt), 4);
    double seed[3];
    f.read(reinterpret_cast<char*>(seed), sizeof seed);
    std::vector<double> nodes(3 * static_cast<size_t>(nn));
    std::vector<int> tets(4 * static_cast<size_t>(nt));
    f.read(reinterpret_cast<char*>(nodes.data()), static_cast<std::streamsize>(nodes.size() * sizeof(double)));
    f.read(reinterpret_cast<char*>(tets.data()), static_cast<std::streamsize>(tets.size() * sizeof(int)));
    if (!f) {
        std::fprintf(stderr, "cannot read %s\n", argv[1]);
        return 2;
    }
    const int reps = argc > 2 ? std::atoi(argv[2]) : 10;
    const SpMat a = system_matrix(nodes, tets);
    std::printf("%s: %d nodes, %d tets; SIMD level %d; best of %d\n", argv[1], nn, nt, detected_simd_level(), reps);
    VecX b = VecX::Random(a.rows());
    BlockLDLT up;
    up.analyze(a);
    const double t_up = best_of(reps, [&] { up.factorize(a); });
    BlockLDLT sn;
    sn.set_supernodal(true);
    sn.analyze(a);
    const double t_sn = best_of(reps, [&] { sn.factorize(a); });
    const VecX x_one = sn.solve(b);
    std::printf("factor flops %.3g; supernodes %d; parts %d\n", up.factor_flops(), sn.supernodes(), sn.factor_parts());
    std::printf("  up-looking            %8.2f ms  %5.1f Gflop/s  residual %.1e\n", 1e3 * t_up, 1e-9 * up.factor_flops() / t_up,
                (a * up.solve(b) - b).norm() / b.norm());
    std::printf("  supernodal, 1 thread  %8.2f ms  %5.1f Gflop/s  residual %.1e\n", 1e3 * t_sn, 1e-9 * sn.factor_flops() / t_sn,
                (a * x_one - b).norm() / b.norm());
    if (sn.factor_parts() == 2) {
        double part[2] = {0, 0};
        for (int p = 0; p < 2; ++p) part[p] = best_of(reps, [&] { sn.factorize_part(a, p); sn.discard_parts(); });
        // the parts side by side, then the rest with its large supernodes' updates in two shares
        Worker worker;
        const Beside beside = [&](const std::function<void()>& mine, const std::function<void()>& other) {
            worker.start(other);
            mine();
            worker.join();
        };
        const double t_two = best_of(reps, [&] {
            worker.start([&] { sn.factorize_part(a, 1); });
            sn.factorize_part(a, 0);
            worker.join();
            sn.factorize(a, beside);
        });
        // the rest alone (the parts done beforehand): on one thread, and with its two shares
        double rest[2] = {1e300, 1e300};
        for (int r = 0; r < reps; ++r)
            for (int shared = 0; shared < 2; ++shared) {
                sn.factorize_part(a, 0);
                sn.factorize_part(a, 1);
                const auto t0 = std::chrono::steady_clock::now();
                sn.factorize(a, shared ? beside : Beside());
                rest[shared] = std::min(rest[shared], std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
            }
        const VecX x_two = sn.solve(b);
        std::printf("  supernodal, 2 threads %8.2f ms  (parts %.2f and %.2f ms alone); same factor as on one thread: %s\n",
                    1e3 * t_two, 1e3 * part[0], 1e3 * part[1], x_two == x_one ? "yes" : "NO");
        std::printf("  the rest alone: one thread %.2f ms, two shares side by side %.2f ms\n", 1e3 * rest[0], 1e3 * rest[1]);
        std::printf("  ratios: supernodal / up-looking %.2f, two threads / one %.2f, rest in shares / alone %.2f\n", t_sn / t_up,
                    t_two / t_sn, rest[1] / rest[0]);
    } else {
        std::printf("  ratio: supernodal / up-looking %.2f\n", t_sn / t_up);
    }
    return 0;
}
