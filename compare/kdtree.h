// Transitional, until the workflows under shadow/ include core/kdtree.h: KdTree, Neighbor and
// SpatialOrder live in core (core/kdtree.h), the median spacing of a tree in
// compare/median_spacing.h.
#pragma once

#include "compare/median_spacing.h"
#include "core/kdtree.h"

namespace slshadow::compare {

using slshadow::KdTree;
using slshadow::Neighbor;
using slshadow::SpatialOrder;

}  // namespace slshadow::compare
