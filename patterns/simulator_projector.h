// What the simulator needs of a rig and a pattern spec, checked in one place.
#pragma once

#include <string>

#include "core/rig.h"
#include "patterns/pattern_spec.h"

namespace slshadow {

// A projector (else "<rig_what>: rig has no projector: the simulator needs one") of the spec's
// size (CheckProjectorSize, naming spec_what and rig_what). Called by `slshadow simulate`
// (pipeline::SimulateFromSpec), the virtual multi-view project and the Python module's simulate.
void CheckSimulatorProjector(const Rig& rig, const PatternSpec& spec, const std::string& spec_what,
                             const std::string& rig_what);

}  // namespace slshadow
