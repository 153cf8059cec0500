// Internal to sim/: cv::Mat storage recycled through a process-wide pool of page-aligned blocks,
// shared by the geometry pass (sim/geometry_pass.cc) and the pattern pass (sim/renderer.cc).
#pragma once

#include <opencv2/core.hpp>

namespace slshadow {

// The allocator behind CreatePooled (never destroyed: Mats may outlive statics).
cv::MatAllocator* PooledMats();

// (Re)creates `m` as rows x cols of `type` in a pooled block: no first-touch page faults once a
// block of that size class has been freed before. Not zeroed: the caller writes every element.
void CreatePooled(cv::Mat& m, int rows, int cols, int type);

}  // namespace slshadow
