#pragma once
// The viewer page template (web/ bundled by esbuild at build time: three.js,
// the viewer's script and styles inline), compiled into the library so that
// `cityforge view` needs no file beside the binary.
#include <string_view>

namespace cityforge {

/// The HTML template; its data goes where the `<!--CITYFORGE_DATA-->` placeholder is.
std::string_view viewer_page_template();

}  // namespace cityforge
