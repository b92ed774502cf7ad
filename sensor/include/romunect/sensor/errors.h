// The one exception type of romunect: bad input from outside (files, JSON, CLI arguments,
// devices). It is thrown only by code that reads such input and caught once, in the CLI.
// Programmer errors use ROMUNECT_CHECK (check.h); per-frame numeric events never throw.
#pragma once

#include <stdexcept>
#include <string>

namespace romunect {

// What a validator found, as structure for callers that name the field their own way (a CLI
// option, a key path under a file's section): `field` is the key path within the validated
// value ("camera", "chip.window_px"; "" for the value as a whole), `rule` what is wrong and what
// was expected. Empty when the value is valid. ToString() is the prose shown: "field: rule".
struct FieldProblem {
  std::string field;
  std::string rule;

  explicit operator bool() const { return !rule.empty(); }
  std::string ToString() const { return field.empty() || rule.empty() ? rule : field + ": " + rule; }
};

class InputError : public std::runtime_error {
 public:
  // `source` names where the input came from (a file path, "--voxel", a device URI),
  // `field` the part that is wrong (a JSON key path, a channel, a pixel), `problem` says
  // what was found and what was expected. The message reads "source: field: problem".
  InputError(const std::string& source, const std::string& field, const std::string& problem)
      : std::runtime_error(Compose(source, field, problem)), source_(source), field_(field), problem_(problem) {}

  const std::string& source() const { return source_; }
  const std::string& field() const { return field_; }
  const std::string& problem() const { return problem_; }

 private:
  static std::string Compose(const std::string& source, const std::string& field, const std::string& problem) {
    std::string message = source;
    if (!field.empty()) message += ": " + field;
    return message + ": " + problem;
  }

  std::string source_;
  std::string field_;
  std::string problem_;
};

}  // namespace romunect
