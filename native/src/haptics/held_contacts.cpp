#include "haptics/held_contacts.h"

#include <algorithm>
#include <cmath>

#include "sim/world.h"

namespace hh {

HeldContacts held_contacts_of(const World& world, int hand) {
    HeldContacts out;
    const int nc = static_cast<int>(world.contact_lambda.size() / 3);
    if (nc == 0 || !world.contact_bodies.count(hand)) return out;
    const VecX& lambda = world.contact_lambda;
    const VecX& u = world.contact_velocity;
    // the contacts of the hand's groups
    std::vector<char> group(world.contact_groups.size(), 0);
    for (int row : world.contact_bodies.at(hand).rows) group[world.contact_group_of[row / 3]] = 1;
    double scale = 0;
    for (int c = 0; c < nc; ++c) scale = std::max(scale, lambda[3 * c]);
    // a contact slides when its tangential velocity is well above the sweeps' tolerance
    const double slip = 10 * world.settings.tolerance;
    for (int c = 0; c < nc; ++c) {
        if (!group[world.contact_group_of[c]] || !(lambda[3 * c] > 1e-9 * scale)) continue;
        // (a frictionless contact slides whatever its velocity: it holds no tangential impulse)
        out.slides.push_back(std::hypot(u[3 * c + 1], u[3 * c + 2]) > slip || world.contact_friction[c] == 0);
        for (int k = 0; k < 3; ++k) out.rows.push_back(3 * c + k);
    }
    return out;
}

MatX held_contact_term(const World& world, const HeldContacts& held, const MatX& hr, const MatX& hl) {
    const std::vector<int>& rows = held.rows;
    const int nr = held.n_rows();
    const VecX& lambda = world.contact_lambda;
    const VecX& u = world.contact_velocity;
    const MatX w = world.contact_delassus(rows);  // the step's W on those rows (unsymmetrized)
    MatX mat = w, rhs_map = MatX::Identity(nr, nr);
    // Redundant contacts make W singular; a compliance of 1e-9 of its largest diagonal entry
    // picks the least-norm impulses without changing the response.
    const double reg = 1e-9 * w.diagonal().cwiseAbs().maxCoeff() + 1e-300;
    for (int a = 0; a < nr; ++a) mat(a, a) += reg;
    for (int h = 0; h < nr / 3; ++h) {
        if (!held.slides[h]) continue;
        const int c = rows[3 * h] / 3, n = 3 * h;
        const Eigen::Vector2d ut(u[3 * c + 1], u[3 * c + 2]);
        const double speed = ut.norm();
        const Eigen::Vector2d dir = speed > 0 ? Eigen::Vector2d(ut / speed) : Eigen::Vector2d::Zero();
        const double mu = std::hypot(lambda[3 * c + 1], lambda[3 * c + 2]) / lambda[3 * c];
        const double s = speed > 0 ? mu * lambda[3 * c] / speed : 0.0;
        const Eigen::Matrix2d p = Eigen::Matrix2d::Identity() - dir * dir.transpose();
        mat.middleRows<2>(n + 1) = s * p * w.middleRows<2>(n + 1);
        mat.block<2, 2>(n + 1, n + 1) += Eigen::Matrix2d::Identity();
        mat.block<2, 1>(n + 1, n) += mu * dir;
        rhs_map.block<2, 2>(n + 1, n + 1) = s * p;
    }
    return hl * mat.partialPivLu().solve(rhs_map * hr);
}

int carrying_rows(const World& world, const HeldContacts& held) {
    int out = 0;
    for (int h = 0; h < held.n_rows() / 3; ++h) out += world.contact_friction[held.rows[3 * h] / 3] == 0 ? 1 : 3;
    return out;
}

}  // namespace hh
