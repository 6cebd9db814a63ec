// The contacts a handle-space model holds (docs/haptics.md, "The two loops"): of the last world
// step, every contact of the hand's contact groups that pushed keeps its normal velocity; one
// that stuck keeps its tangential velocity zero; one that slid keeps its friction on the rim
// against its sliding velocity. Shared by the palm handle's model (haptics/coupling_model.cpp)
// and the B-bone model (haptics/bone_coupling_model.cpp), which differ only in how many handle
// columns H_r and H_l have (6 or 6B).
#pragma once
#include <vector>

#include "common/types.h"

namespace hh {

class World;

struct HeldContacts {
    std::vector<int> rows;     // global contact rows, 3 per held contact
    std::vector<char> slides;  // per held contact
    int n_rows() const { return static_cast<int>(rows.size()); }
};

// The held contacts of hand body `hand` after the world's last step (none without contact).
HeldContacts held_contacts_of(const World& world, int hand);

// H_l M^-1 N H_r (handles x handles): the flesh part of the model that the held contacts take
// back, with H_r = J A_t^-1 Ath (rows x handles) and H_l = Aht_e A_t^-1 J^T (handles x rows)
// on the held rows. M dlambda = N H_r dv_h: normal and sticking rows keep their velocity
// (W dlambda = H_r dv_h); a sliding contact's tangent rows, with s = mu lambda_n / |u_t| and P
// the projection off u_t: dlambda_t + mu u^ dlambda_n + s P (W dlambda - H_r dv_h)_t = 0.
MatX held_contact_term(const World& world, const HeldContacts& held, const MatX& hr, const MatX& hl);

// The contact rows that carry impulse among the held ones (the normal rows, and the tangent
// rows of contacts with friction): the models' held_rows.
int carrying_rows(const World& world, const HeldContacts& held);

}  // namespace hh
