// Anchor translation unit for the math library (its code is header templates).
#include "engine/math/types.h"
