#include "params/table.h"

#include <charconv>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <sstream>

#include "common/types.h"

namespace hh::params {

namespace {

// One hh_param_info from a row of the table; STRUCT_ID and STRUCT_TYPE are set around each list.
#define HH_INFO(name, kind, count, json, unit, def, lo, hi, flags, soft_lo, soft_hi, label, text, desc, \
                advice)                                                                               \
    hh_param_info{sizeof(hh_param_info), #name, json, unit, label, text, desc, advice, kind, count,      \
                  flags, STRUCT_ID, STRUCT_OFFSET(name), def, lo, hi, soft_lo, soft_hi},

std::vector<hh_param_info> make_rows() {
    return {
#define STRUCT_ID HH_STRUCT_PARAMS
#define STRUCT_OFFSET(name) static_cast<int>(offsetof(hh_params, name))
        HH_PARAMS_ROWS(HH_INFO)
#undef STRUCT_ID
#undef STRUCT_OFFSET
#define STRUCT_ID HH_STRUCT_WORLD_PARAMS
#define STRUCT_OFFSET(name) static_cast<int>(offsetof(hh_world_params, name))
        HH_WORLD_PARAMS_ROWS(HH_INFO)
#undef STRUCT_ID
#undef STRUCT_OFFSET
#define STRUCT_ID HH_STRUCT_MATERIAL
#define STRUCT_OFFSET(name) static_cast<int>(offsetof(hh_material, name))
        HH_MATERIAL_STRUCT_ROWS(HH_INFO)
#undef STRUCT_ID
#undef STRUCT_OFFSET
#define STRUCT_ID HH_STRUCT_SESSION_PARAMS
#define STRUCT_OFFSET(name) static_cast<int>(offsetof(hh_session_params, name))
        HH_SESSION_PARAMS_ROWS(HH_INFO)
#undef STRUCT_ID
#undef STRUCT_OFFSET
#define STRUCT_ID HH_STRUCT_NONE
#define STRUCT_OFFSET(name) -1
        HH_SCENE_ROWS(HH_INFO)
#undef STRUCT_ID
#undef STRUCT_OFFSET
    };
}
#undef HH_INFO

std::string number(double v) {
    std::ostringstream s;
    s << v;
    return s.str();
}

// The enum's choices "a|b|c" as a list.
std::vector<std::string> choices(const hh_param_info& r) {
    std::vector<std::string> out;
    std::string item;
    for (const char* c = r.text;; ++c) {
        if (*c == '|' || *c == '\0') {
            out.push_back(item);
            item.clear();
            if (*c == '\0') break;
        } else {
            item += *c;
        }
    }
    return out;
}

std::string interval(const hh_param_info& r) {
    const bool open_lo = r.flags & HH_OPEN_MIN, open_hi = r.flags & HH_OPEN_MAX;
    const bool lo = std::isfinite(r.min), hi = std::isfinite(r.max);
    if (!lo && !hi) return "finite";
    if (lo && !hi) {
        if (r.min == 0) return open_lo ? "positive" : "zero or positive";
        return (open_lo ? "greater than " : "at least ") + number(r.min);
    }
    if (!lo) return (open_hi ? "below " : "at most ") + number(r.max);
    return std::string("in ") + (open_lo ? "(" : "[") + number(r.min) + ", " + number(r.max) + (open_hi ? ")" : "]");
}

bool in_range(const hh_param_info& r, double v) {
    if (!std::isfinite(v)) return false;
    if ((r.flags & HH_ZERO_OR_RANGE) && v == 0) return true;
    if (r.kind == HH_KIND_BOOL) return v == 0 || v == 1;
    if (r.kind == HH_KIND_ENUM) return v == std::floor(v) && v >= 0 && v < choices(r).size();
    if (r.kind == HH_KIND_INT && v != std::floor(v)) return false;
    const bool lo_ok = (r.flags & HH_OPEN_MIN) ? v > r.min : v >= r.min;
    const bool hi_ok = (r.flags & HH_OPEN_MAX) ? v < r.max : v <= r.max;
    return lo_ok && hi_ok;
}

// The JSON path, with the C field's name when the path's last part differs from it
// ("springs.stiffness (spring_stiffness)"), so users of the scene file and of the C or Python
// structs both find their field.
std::string field_name(const hh_param_info& r) {
    const std::string json = r.json, name = r.name;
    if (json.empty()) return name;
    const std::size_t dot = json.rfind('.');
    const std::string leaf = dot == std::string::npos ? json : json.substr(dot + 1);
    return leaf == name || r.structure == HH_STRUCT_NONE ? json : json + " (" + name + ")";
}

// The shortest text that reads back as v: a stream's six digits would show 1000001, just over
// the frames cap, as "1e+06".
std::string exact(double v) {
    char text[32];
    const std::to_chars_result end = std::to_chars(text, text + sizeof text, v);
    return std::string(text, end.ptr);
}

}  // namespace

const std::vector<hh_param_info>& rows() {
    static const std::vector<hh_param_info> table = make_rows();
    return table;
}

const hh_param_info& row(const char* json) {
    for (const hh_param_info& r : rows())
        if (std::strcmp(r.json, json) == 0) return r;
    throw InvalidArgument(std::string("'") + json + "' is not a parameter (docs/scene_format.md lists them)");
}

std::string rule(const hh_param_info& r) {
    std::string out;
    if (r.kind == HH_KIND_BOOL) return "true or false";
    if (r.kind == HH_KIND_ENUM) {
        const std::vector<std::string> c = choices(r);
        out = "one of";
        for (std::size_t i = 0; i < c.size(); ++i) out += (i ? ", " : " ") + c[i] + " (" + std::to_string(i) + ")";
        return out;
    }
    out = interval(r);
    if (r.kind == HH_KIND_INT) out = "a whole number " + out;
    if (r.flags & HH_ZERO_OR_RANGE) out = "0, or " + out;
    if (r.unit[0]) out += std::string(" (") + r.unit + ")";
    return out;
}

void check(const hh_param_info& r, const double* values, int count) {
    if (count != r.count)
        throw InvalidArgument(field_name(r) + " takes " + std::to_string(r.count) + " number(s), got " +
                              std::to_string(count));
    for (int i = 0; i < count; ++i) {
        if (in_range(r, values[i])) continue;
        std::ostringstream msg;
        msg << field_name(r);
        if (count > 1) msg << "[" << i << "]";
        msg << " = " << exact(values[i]) << " is invalid: it must be " << rule(r) << "; " << r.advice;
        throw InvalidArgument(msg.str());
    }
}

int struct_size(int structure) {
    switch (structure) {
        case HH_STRUCT_PARAMS: return sizeof(hh_params);
        case HH_STRUCT_WORLD_PARAMS: return sizeof(hh_world_params);
        case HH_STRUCT_MATERIAL: return sizeof(hh_material);
        case HH_STRUCT_SESSION_PARAMS: return sizeof(hh_session_params);
        case HH_STRUCT_SKELETON_DESC: return sizeof(hh_skeleton_desc);
        case HH_STRUCT_BONE_INFO: return sizeof(hh_bone_info);
        case HH_STRUCT_MODEL_INFO: return sizeof(hh_model_info);
        case HH_STRUCT_STEP_STATS: return sizeof(hh_step_stats);
        case HH_STRUCT_WORLD_STATS: return sizeof(hh_world_stats);
        case HH_STRUCT_SESSION_STATUS: return sizeof(hh_session_status);
        case HH_STRUCT_SESSION_FRAME: return sizeof(hh_session_frame);
        default: throw InvalidArgument("unknown struct " + std::to_string(structure) + " (HH_STRUCT_*)");
    }
}

void fill_defaults(int structure, void* s) {
    const int size = struct_size(structure);
    std::memset(s, 0, size);
    std::memcpy(s, &size, sizeof(int));  // struct_size comes first in every struct
    char* base = static_cast<char*>(s);
    for (const hh_param_info& r : rows()) {
        if (r.structure != structure) continue;
        for (int i = 0; i < r.count; ++i) {
            if (r.kind == HH_KIND_DOUBLE)
                reinterpret_cast<double*>(base + r.offset)[i] = r.default_value[i];
            else
                reinterpret_cast<int*>(base + r.offset)[i] = static_cast<int>(r.default_value[i]);
        }
    }
}

void validate(int structure, const void* s) {
    int given = 0;
    std::memcpy(&given, s, sizeof(int));
    if (given != struct_size(structure))
        throw InvalidArgument("a parameter struct has the wrong size (struct_size " + std::to_string(given) +
                              "): the caller and the native library are from different versions; rebuild the "
                              "native library (make native) and the bindings");
    const char* base = static_cast<const char*>(s);
    for (const hh_param_info& r : rows()) {
        if (r.structure != structure) continue;
        double v[3];
        for (int i = 0; i < r.count; ++i)
            v[i] = r.kind == HH_KIND_DOUBLE ? reinterpret_cast<const double*>(base + r.offset)[i]
                                            : reinterpret_cast<const int*>(base + r.offset)[i];
        check(r, v, r.count);
    }
}

}  // namespace hh::params
