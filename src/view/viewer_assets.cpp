#include "view/viewer_assets.hpp"

// The template file is named by CMake (CITYFORGE_VIEWER_TEMPLATE) and pulled
// in by the assembler, so the compiler never parses half a megabyte of script.
__asm__(".section .rodata\n"
        ".balign 16\n"
        ".global cityforge_viewer_template_begin\n"
        "cityforge_viewer_template_begin:\n"
        ".incbin \"" CITYFORGE_VIEWER_TEMPLATE "\"\n"
        ".global cityforge_viewer_template_end\n"
        "cityforge_viewer_template_end:\n"
        ".byte 0\n"
        ".previous\n");

extern "C" const char cityforge_viewer_template_begin[];
extern "C" const char cityforge_viewer_template_end[];

namespace cityforge {

std::string_view viewer_page_template() {
    return {cityforge_viewer_template_begin, static_cast<std::size_t>(cityforge_viewer_template_end - cityforge_viewer_template_begin)};
}

}  // namespace cityforge
