#include "formats/shot/shot_file.h"
