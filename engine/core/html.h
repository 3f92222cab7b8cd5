#pragma once
// Text for the HTML reports (validate, calibrate, hdr): the one escape they share.
#include <string>

namespace reflcap {

// `text` with &, <, > and " replaced by their entities: safe inside an element or a quoted
// attribute.
std::string HtmlEscape(const std::string& text);

}  // namespace reflcap
