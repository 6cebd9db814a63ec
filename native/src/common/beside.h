// Two jobs that may run side by side on two threads (World::step's task graph,
// TaskGraph::run_beside): the call returns once both are done. Empty: the caller runs them one
// after the other. Whoever offers a split keeps its result the same either way.
#pragma once
#include <functional>

namespace hh {

using Beside = std::function<void(const std::function<void()>&, const std::function<void()>&)>;

}  // namespace hh
