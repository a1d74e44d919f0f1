// canopy: the command-line tool.
//
// Exit status: 0 success; 1 bad input or a failed build (the first line on
// stderr says what and where); 2 usage error; 3 validation failed.
#include "cli.h"

#include <iostream>
#include <new>
#include <vector>

int main(int argc, char** argv) {
    using namespace canopy::cli;
    CLI::App app{"canopy: parallel binned-SAH BVH builder"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "canopy 0.1.0");
    std::vector<Runner> verbs = {add_build(app), add_info(app), add_bench(app), add_sweep(app), add_render(app)};
    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        std::cerr << "Run 'canopy --help' or 'canopy VERB --help'.\n";
        return kUsage;
    }
    try {
        for (const Runner& run : verbs) {
            const int status = run();
            if (status >= 0) return status;
        }
    } catch (const UsageError& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        return kUsage;
    } catch (const canopy::OptionError& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        return kUsage;
    } catch (const canopy::Error& e) {
        std::cerr << "canopy: " << e.what() << "\n";
        return kInput;
    } catch (const std::bad_alloc&) {
        std::cerr << "canopy: out of memory\n";
        return kInput;
    }
    return kUsage;
}
