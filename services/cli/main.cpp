#include "services/cli/cli.h"

int main(int argc, char** argv) { return pbgi::cli::run(argc, argv); }
