// The parameter table as the library uses it: defaults that pass their own checks, every range
// enforced with a message naming the field, rows shared by two structs identical, offsets and
// sizes consistent with the structs the header builds.
#include <cmath>
#include <cstddef>
#include <cstring>
#include <string>

#include "check.h"
#include "haptic_hand.h"
#include "common/types.h"
#include "params/table.h"

namespace {

bool same_row(const hh_param_info& a, const hh_param_info& b) {
    return std::strcmp(a.name, b.name) == 0 && a.kind == b.kind && a.count == b.count && a.flags == b.flags &&
           a.min == b.min && a.max == b.max && std::memcmp(a.default_value, b.default_value, sizeof(a.default_value)) == 0;
}

// A value the row must refuse (just outside its range, or not a whole number / choice).
bool outside(const hh_param_info& r, double& v) {
    if (r.kind == HH_KIND_BOOL) return v = 2, true;
    if (r.kind == HH_KIND_ENUM) return v = 99, true;
    if (std::isfinite(r.min) && !(r.flags & HH_ZERO_OR_RANGE && r.min > 0))
        return v = (r.flags & HH_OPEN_MIN) ? r.min : r.min - 1, true;
    if (std::isfinite(r.max)) return v = (r.flags & HH_OPEN_MAX) ? r.max : r.max + 1, true;
    return v = NAN, true;
}

}  // namespace

TEST(every_struct_default_passes_its_own_checks) {
    hh_params p;
    hh_world_params w;
    hh_material m;
    hh_session_params s;
    hh_default_params(&p);
    hh_default_world_params(&w);
    hh_default_material(&m);
    hh_default_session_params(&s);
    hh::params::validate(HH_STRUCT_PARAMS, &p);
    hh::params::validate(HH_STRUCT_WORLD_PARAMS, &w);
    hh::params::validate(HH_STRUCT_MATERIAL, &m);
    hh::params::validate(HH_STRUCT_SESSION_PARAMS, &s);
    CHECK(p.struct_size == static_cast<int>(sizeof p) && w.struct_size == static_cast<int>(sizeof w));
    // the struct fields hold the rows' defaults
    CHECK(p.young_modulus == hh::params::row("material.young_modulus").default_value[0]);
    CHECK(w.dt == p.dt && s.coupling_stiffness == p.coupling_stiffness);
    CHECK(p.gravity[2] == hh::params::row("gravity").default_value[2]);
}

TEST(every_numeric_default_is_in_range_and_every_range_refuses_what_lies_outside) {
    int checked = 0;
    for (const hh_param_info& r : hh::params::rows()) {
        if (r.kind > HH_KIND_ENUM || r.count == 0) continue;
        hh::params::check(r, r.default_value, r.count);  // throws if a default is out of its range
        double bad = 0;
        CHECK(outside(r, bad));
        double values[3] = {r.default_value[0], r.default_value[1], r.default_value[2]};
        values[r.count - 1] = bad;
        bool refused = false;
        try {
            hh::params::check(r, values, r.count);
        } catch (const hh::InvalidArgument& e) {
            refused = true;
            const std::string name = r.json[0] ? r.json : r.name;
            CHECK(std::string(e.what()).find(name) == 0);              // names the field first
            CHECK(std::string(e.what()).find("it must be") != std::string::npos);
            CHECK(std::string(e.what()).find(r.advice) != std::string::npos);  // and a good value
        }
        CHECK(refused);
        ++checked;
    }
    CHECK(checked > 40);
}

TEST(a_row_two_structs_share_is_the_same_row) {
    for (const char* json : {"dt", "gravity", "coupling.stiffness", "coupling.angular_damping"}) {
        int found = 0;
        const hh_param_info& first = hh::params::row(json);
        for (const hh_param_info& r : hh::params::rows())
            if (std::strcmp(r.json, json) == 0) {
                CHECK(same_row(first, r));
                ++found;
            }
        CHECK(found == 2);
    }
}

TEST(offsets_and_sizes_match_the_structs) {
    CHECK(hh::params::row("springs.stiffness").offset == static_cast<int>(offsetof(hh_params, spring_stiffness)));
    CHECK(hh::params::row("contact.threads").offset == static_cast<int>(offsetof(hh_world_params, threads)));
    int size = 0;
    CHECK(hh_struct_size(HH_STRUCT_SESSION_PARAMS, &size) == HH_OK && size == static_cast<int>(sizeof(hh_session_params)));
    CHECK(hh_struct_size(77, &size) == HH_ERR_INVALID_ARGUMENT);
    // every field of every struct is a row (the structs are built from them, nothing else)
    std::size_t bytes = sizeof(int);
    for (const hh_param_info& r : hh::params::rows())
        if (r.structure == HH_STRUCT_PARAMS) bytes += r.count * (r.kind == HH_KIND_DOUBLE ? sizeof(double) : sizeof(int));
    CHECK(bytes <= sizeof(hh_params) && sizeof(hh_params) - bytes < 4 * sizeof(double));  // padding only
}

TEST(a_struct_from_another_version_is_refused) {
    hh_params p;
    hh_default_params(&p);
    p.struct_size -= 8;
    hh_model* m = nullptr;
    const double x[15] = {0};
    const int t[4] = {0, 1, 2, 3};
    CHECK(hh_model_create(x, 5, t, 1, &p, &m) == HH_ERR_INVALID_ARGUMENT);
    CHECK(std::string(hh_last_error()).find("different versions") != std::string::npos);
}

TEST(the_c_entry_point_checks_scene_fields_too) {
    double v = -1;
    CHECK(hh_param_check("haptics.arm.mass", &v, 1) == HH_ERR_INVALID_ARGUMENT);
    CHECK(std::string(hh_last_error()).find("haptics.arm.mass = -1") == 0);
    v = 2;
    CHECK(hh_param_check("frames", &v, 1) == HH_OK);
    v = 2.5;
    CHECK(hh_param_check("frames", &v, 1) == HH_ERR_INVALID_ARGUMENT);
    CHECK(hh_param_check("no.such.field", &v, 1) == HH_ERR_INVALID_ARGUMENT);
    CHECK(hh_param_check("gravity", &v, 1) == HH_ERR_INVALID_ARGUMENT);  // takes 3 numbers
}

