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
};

// Signed volume det[x1-x0, x2-x0, x3-x0] / 6.
double tet_signed_volume(const Vec3& x0, const Vec3& x1, const Vec3& x2, const Vec3& x3);

// Throws InvalidArgument naming the first inverted or zero-volume tet.
CorotationalElements precompute_elements(const TetMesh& mesh, const Material& material);

// Eq. 2: each tet gives a quarter of its mass to each of its nodes.
VecX lumped_masses(const TetMesh& mesh, const CorotationalElements& elements, double density);

// Rotation of the polar decomposition of F (a proper rotation even for inverted elements).
Mat3 element_rotation(const TetMesh& mesh, const CorotationalElements& elements, int e,
                      const VecX& x);

// Adds the elastic forces of all elements to f and returns the elastic energy; if
// rotations is non-null it receives each element's rotation.
double add_elastic_forces(const TetMesh& mesh, const CorotationalElements& elements,
                          const VecX& x, VecX& f, std::vector<Mat3>* rotations);

// Sparse pattern of the 3n x 3n node-node matrix, with for every element the 144 offsets
// of its entries in the value array, so assembly is a scatter with no search.
struct StiffnessPattern {
    SpMat matrix;                      // pattern with zero values, both triangles stored
    std::vector<int> element_offsets;  // 144 per element, row-major over (3a+i, 3b+j)
    std::vector<int> node_block_offsets; // 9 per node: its own 3x3 block, row-major
};
StiffnessPattern build_stiffness_pattern(const TetMesh& mesh);

// values += scale * sum_e R_e Ke R_e^T (the warped stiffness), scattered through the pattern.
void add_warped_stiffness(const CorotationalElements& elements, const std::vector<Mat3>& rotations,
                          const StiffnessPattern& pattern, double scale, double* values);

}  // namespace hh
