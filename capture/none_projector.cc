#include "capture/none_projector.h"

namespace slshadow::capture {

std::chrono::steady_clock::time_point NoneProjector::Show(int /*index*/) {
  return std::chrono::steady_clock::now();
}

}  // namespace slshadow::capture
