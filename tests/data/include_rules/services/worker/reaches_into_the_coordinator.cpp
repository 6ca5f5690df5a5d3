// Crafted for tests/services/include_rules.sh: a worker that includes the coordinator's
// headers instead of services/farm/. The rule check must refuse it.
#include "services/coordinator/coordinator.h"
