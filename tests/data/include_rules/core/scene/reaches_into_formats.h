// Crafted for tests/services/include_rules.sh: core/ including formats/. Must be refused.
#pragma once
#include "formats/shot/shot_file.h"
