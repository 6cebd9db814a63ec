// Linear co-rotational tetrahedral FEM (Mueller & Gross 2004) with lumped masses (Eq. 2).
// Per element: rest shape inverse Bm, volume, linear stiffness Ke (12x12). Per step: the
// element rotation R from the polar decomposition of F = Ds Bm, the elastic force
// f = -R Ke (R^T x - X) and the warped stiffness R Ke R^T.
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

struct TetMesh {
    int n_nodes = 0;
    VecX rest;                             // 3n rest positions X
    std::vector<Eigen::Vector4i> tets;     // positively oriented
};

struct Material {
    double young_modulus;
    double poisson_ratio;
    double density;
};

struct CorotationalElements {
    std::vector<Mat3> rest_inverse;  // Bm = Dm^-1, Dm = [X1-X0, X2-X0, X3-X0]
    std::vector<double> volume;
    std::vector<Mat12> stiffness;    // Ke, rest frame
    std::vector<Eigen::Matrix<double, 4, 3>> gradients;  // shape-function gradients g_a (rows)
    double lambda = 0, mu = 0;       // Lame parameters
};

// Signed volume det[x1-x0, x2-x0, x3-x0] / 6.
double tet_signed_volume(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3);

// Throws InvalidArgument naming the first inverted or zero-volume tet.
CorotationalElements precompute_elements(const TetMesh& mesh, const Material& material);

// Eq. 2: each tet gives a quarter of its mass to each of its nodes.
VecX lumped_masses(const TetMesh& mesh, const CorotationalElements& elements, double density);

// Per-element rotations, kept between steps: each step's polar decomposition starts from
// the previous step's rotation, so it converges in one or two iterations.
struct ElementRotations {
    std::vector<Vec4> q;  // unit quaternions (x, y, z, s)
    std::vector<Mat3> r;  // the same as matrices
};

// Deformation gradient F = Ds Bm of element e.
Mat3 deformation_gradient(const TetMesh& mesh, const CorotationalElements& elements, int e, const VecX& x);

// Rotation of the polar decomposition of F, for any F: the proper rotation R maximizing
// trace(R^T F). For an inverted element (det F < 0) that is the SVD's U V^T with the smallest
// singular direction flipped (McAdams et al. 2011), so R stays proper and pushes the element
// back out. Newton's iteration of Mueller, Bender, Chentanez & Macklin 2016 from the guess q
// (updated in place), guarded: a result is kept only where it converged at a maximum (positive
// definite Hessian) within kPolarNewtonSteps; otherwise the SVD gives it (polar_rotation_svd).
Mat3 polar_rotation(const Mat3& f, Vec4& q);
// The same from the SVD alone (q receives it); a non-finite F leaves q as it was.
Mat3 polar_rotation_svd(const Mat3& f, Vec4& q);
// Newton steps polar_rotation allows before the SVD: a warm start converges in one or two.
constexpr int kPolarNewtonSteps = 8;
// Converged when the Newton step's squared angle is below this (a step under 1e-9 rad, then taken).
constexpr double kPolarConverged = 1e-18;

// Adds the elastic forces of all elements to f and returns the elastic energy. rotations,
// if non-null, supplies warm starts (when sized for the mesh) and receives the rotations.
double add_elastic_forces(const TetMesh& mesh, const CorotationalElements& elements,
                          const VecX& x, VecX& f, ElementRotations* rotations);

// Sparse pattern of the 3n x 3n node-node matrix, with for every element the 144 offsets
// of its entries in the value array, so assembly is a scatter with no search.
struct StiffnessPattern {
    SpMat matrix;                      // pattern with zero values, both triangles stored
    std::vector<int> element_offsets;  // 144 per element, row-major over (3a+i, 3b+j)
    std::vector<int> node_block_offsets; // 9 per node: its own 3x3 block, row-major
    // The compact form used by assembly: the three columns of a node share one row pattern
    // made of whole 3x3 blocks, so entry (3 t_a + i, 3 t_b + j) of element e sits at
    // element_blocks[16 e + 4 a + b] + j * column_length[t_b] + i.
    std::vector<int> element_blocks;   // 16 per element
    std::vector<int> column_length;    // per node: entries in each of its 3 columns
};
StiffnessPattern build_stiffness_pattern(const TetMesh& mesh);

// values += scale * sum_e R_e Ke R_e^T (the warped stiffness), scattered through the pattern.
void add_warped_stiffness(const CorotationalElements& elements, const std::vector<Mat3>& rotations,
                          const StiffnessPattern& pattern, double scale, double* values);

// The whole per-step element pass in one loop (what add_elastic_forces and
// add_warped_stiffness do, fused and cheaper): each element's rotation (warm-started polar
// decomposition, rotations sized for the mesh or resized), its elastic force -V R sigma g_a
// added to f (sigma = lambda tr(e) I + 2 mu e, e = sym(R^T F) - I, the same as -R Ke u),
// scale * R Ke R^T added to values through the pattern's compact offsets. Returns the energy.
double assemble_corotational(const TetMesh& mesh, const CorotationalElements& elements, const VecX& x, VecX& f,
                             ElementRotations& rotations, const StiffnessPattern& pattern, double scale, double* values);
// The same over elements [begin, end) only, the rotations already sized for the mesh
// (size_rotations): parts of the pass that touch disjoint nodes may run at the same time.
void size_rotations(ElementRotations& rotations, size_t elements);
double assemble_corotational(const TetMesh& mesh, const CorotationalElements& elements, const VecX& x, VecX& f,
                             ElementRotations& rotations, const StiffnessPattern& pattern, double scale, double* values,
                             size_t begin, size_t end);

}  // namespace hh
