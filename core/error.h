// canopy: the library's one error type.
//
// Policy: every failure the library reports is a C++ exception derived from
// canopy::Error. The message names what is wrong and where (file, line,
// element, primitive index). Nothing is reported through return codes.
#pragma once

#include <stdexcept>
#include <string>

namespace canopy {

class Error : public std::runtime_error {
public:
    explicit Error(const std::string& what) : std::runtime_error(what) {}
};

// Bad input data: malformed files, non-finite coordinates, indices out of
// range, limits exceeded.
class InputError : public Error {
public:
    explicit InputError(const std::string& what) : Error(what) {}
};

// Invalid build options (bins out of range, leaf size too large, ...).
class OptionError : public Error {
public:
    explicit OptionError(const std::string& what) : Error(what) {}
};

}  // namespace canopy
