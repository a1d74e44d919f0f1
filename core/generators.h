// canopy: the seeded scene generators behind "gen:NAME:COUNT[:SEED]" specs
// (listed in scene.h, which declares generate() and generator_names()).
#pragma once

#include "scene.h"

#include <string>

namespace canopy {

// Runs the generator a spec names; InputError naming the spec and what is
// wrong with it (with the list of generators) otherwise.
Scene load_generator_spec(const std::string& spec);

}  // namespace canopy
