// The wrench a haptic loop commands to a device (device.h): what the user's hand is pushed by.
#pragma once
#include "common/types.h"

namespace hh {

struct Feedback {
    Vec3 force = Vec3::Zero();   // N, on the device (the user's hand)
    Vec3 torque = Vec3::Zero();  // N m
};

}  // namespace hh
