#include "romunect/sensor/input_limits.h"

#include <cctype>
#include <cerrno>
#include <cstring>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <opencv2/core.hpp>

#include "romunect/sensor/errors.h"

namespace romunect {
namespace {

class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

}  // namespace

std::string ReadInputFile(const std::filesystem::path& path, size_t max_bytes, const std::string& what) {
  const std::string source = path.string();
  if (source.find('\0') != std::string::npos) throw InputError(source, "", "a path may not hold a NUL character");
  // O_NONBLOCK: opening a FIFO without a writer must not wait; a regular file ignores the flag.
  const Fd fd(::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY));
  if (fd.get() < 0) {
    if (errno == ENOENT) throw InputError(source, "", "file not found");
    throw InputError(source, "", "cannot be opened: " + std::string(std::strerror(errno)));
  }
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0) throw InputError(source, "", "cannot be read: " + std::string(std::strerror(errno)));
  if (S_ISDIR(st.st_mode)) throw InputError(source, "", "is a folder, not a " + what);
  if (!S_ISREG(st.st_mode)) {
    throw InputError(source, "", "is not a regular file (a FIFO, device or socket); expected a " + what);
  }
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    throw InputError(source, "",
                     "is " + std::to_string(st.st_size) + " bytes; a " + what + " may be at most " +
                         std::to_string(max_bytes) + " bytes");
  }
  std::string bytes(static_cast<size_t>(st.st_size), '\0');
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::read(fd.get(), bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw InputError(source, "", "cannot be read: " + std::string(std::strerror(errno)));
    if (n == 0) break;  // shrank while read: parse what is there, which then fails as truncated
    done += static_cast<size_t>(n);
  }
  bytes.resize(done);
  return bytes;
}

void CheckJsonNesting(std::string_view text, const std::string& source) {
  int depth = 0;
  bool in_string = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      if (c == '\\') {
        ++i;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > kMaxJsonDepth) {
        throw InputError(source, "",
                         "nests arrays and objects deeper than " + std::to_string(kMaxJsonDepth) + " levels (at byte " +
                             std::to_string(i) + ")");
      }
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
}

void CheckYamlNesting(std::string_view text, const std::string& source) {
  // Errs on the side of counting: a bracket or "- " inside a plain scalar counts as nesting.
  int flow_depth = 0;
  int line = 1;
  int dashes = 0;  // block sequence indicators on this line
  bool at_line_start = true;
  char quote = 0;  // the open quote, or 0
  char last = 0;   // the last character outside quotes and spaces on this line, 0 at its start
  int root_indent = -1;  // the first key's column (0-based), once seen
  auto fail = [&](const std::string& what, int limit) {
    throw InputError(source, "line " + std::to_string(line),
                     what + " deeper than " + std::to_string(limit) + " (the limit on nesting of romunect's YAML)");
  };
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '\n') {
      ++line;
      dashes = 0;
      last = 0;
      at_line_start = true;
      continue;
    }
    if (at_line_start && quote == 0 && flow_depth == 0) {
      size_t j = i;
      while (j < text.size() && (text[j] == ' ' || text[j] == '\t')) ++j;
      if (j - i > static_cast<size_t>(kMaxYamlIndent)) fail("indented", kMaxYamlIndent);
      // No line of a document lies left of its first key: that is not YAML, and OpenCV 4.6's
      // parser can loop forever on it (a 20-byte file did).
      const bool content = j < text.size() && std::strchr("\n\r#", text[j]) == nullptr;
      const bool document_marker = j == i && (text.substr(j, 3) == "---" || text.substr(j, 3) == "...");
      const bool marker = document_marker || (j == i && j < text.size() && text[j] == '%');
      if (document_marker) {
        // Content after a marker on its line ("--- a", "----a") starts the document right of the
        // lines below it, which OpenCV 4.6's parser can loop on forever as well.
        size_t k = j + 3;
        while (k < text.size() && (text[k] == ' ' || text[k] == '\t' || text[k] == '\r')) ++k;
        if (k < text.size() && text[k] != '\n' && text[k] != '#') {
          throw InputError(source, "line " + std::to_string(line),
                           "expected the document marker '" + std::string(text.substr(j, 3)) +
                               "' alone on its line (as OpenCV writes it)");
        }
      }
      if (content && !marker) {
        const int indent = static_cast<int>(j - i);
        if (root_indent < 0) {
          root_indent = indent;
        } else if (indent < root_indent) {
          throw InputError(source, "line " + std::to_string(line),
                           "indented less than the document's first key (column " + std::to_string(root_indent + 1) +
                               "): not valid YAML");
        }
      }
    }
    at_line_start = false;
    if (quote == '"') {
      if (c == '\\') {
        ++i;
      } else if (c == '"') {
        quote = 0;
      }
      continue;
    }
    if (quote == '\'') {
      if (c == '\'' && i + 1 < text.size() && text[i + 1] == '\'') {
        ++i;
      } else if (c == '\'') {
        quote = 0;
      }
      continue;
    }
    if (c == ' ' || c == '\t' || c == '\r') continue;
    const bool after_space = i == 0 || text[i - 1] == ' ' || text[i - 1] == '\t' || text[i - 1] == '\n';
    if (c == '#' && after_space) {  // a comment runs to the end of the line
      while (i + 1 < text.size() && text[i + 1] != '\n') ++i;
      continue;
    }
    const bool token_start = after_space || std::strchr("[{,", text[i - 1]) != nullptr;
    if ((c == '"' || c == '\'') && token_start && (last == 0 || std::strchr("[{,:-?", last) != nullptr)) {
      quote = c;
    } else if (c == '[' || c == '{') {
      if (++flow_depth > kMaxYamlDepth) fail("flow collections nest", kMaxYamlDepth);
    } else if ((c == ']' || c == '}') && flow_depth > 0) {
      --flow_depth;
    } else if (c == '-' && after_space && flow_depth == 0 &&
               (i + 1 == text.size() || text[i + 1] == ' ' || text[i + 1] == '\t' || text[i + 1] == '\n')) {
      if (++dashes > kMaxYamlDepth) fail("block sequences nest", kMaxYamlDepth);
    }
    last = c;
  }
}

namespace {

// Element depth of XML text: "<a>" opens, "</a>" and "<a/>" close; comments, declarations and
// attribute values (which may hold '>') are skipped.
void CheckXmlNesting(std::string_view text, const std::string& source) {
  int depth = 0;
  for (size_t i = 0; i + 1 < text.size(); ++i) {
    if (text[i] != '<') continue;
    const char next = text[i + 1];
    if (next == '!' || next == '?') {  // comment or declaration: to its end
      const size_t end = text.find(text.compare(i, 4, "<!--") == 0 ? "-->" : ">", i + 2);
      if (end == std::string_view::npos) return;
      i = end;
      continue;
    }
    if (next == '/') {
      if (depth > 0) --depth;
      continue;
    }
    if (++depth > kMaxYamlDepth) {
      throw InputError(source, "",
                       "nests elements deeper than " + std::to_string(kMaxYamlDepth) + " levels (at byte " +
                           std::to_string(i) + ")");
    }
    char quote = 0;
    for (++i; i < text.size(); ++i) {  // to the tag's end
      const char c = text[i];
      if (quote != 0) {
        if (c == quote) quote = 0;
      } else if (c == '"' || c == '\'') {
        quote = c;
      } else if (c == '>') {
        if (text[i - 1] == '/') --depth;
        break;
      }
    }
  }
}
}  // namespace

cv::FileStorage OpenFileStorage(const std::filesystem::path& path, const std::string& what) {
  const std::string source = path.string();
  const std::string text = ReadInputFile(path, kMaxTextFileBytes, what);
  std::string extension = path.extension().string();
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  int format = cv::FileStorage::FORMAT_YAML;
  if (extension == ".json") {
    format = cv::FileStorage::FORMAT_JSON;
    CheckJsonNesting(text, source);
  } else if (extension == ".xml") {
    format = cv::FileStorage::FORMAT_XML;
    CheckXmlNesting(text, source);
  } else {
    CheckYamlNesting(text, source);
  }
  cv::FileStorage fs;
  try {
    if (!fs.open(text, cv::FileStorage::READ | cv::FileStorage::MEMORY | format)) {
      throw InputError(source, "", "cannot be read by cv::FileStorage");
    }
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {  // cv::Exception, and what OpenCV's parser lets escape (length_error)
    throw InputError(source, "", "not a valid OpenCV " + what + ": " + e.what());
  }
  return fs;
}

void CheckMatrixNode(const cv::FileNode& node, int max_rows, int max_cols, const std::string& source,
                     const std::string& field) {
  const auto fail = [&](const std::string& why) {
    throw InputError(source, field,
                     "not an OpenCV matrix of at most " + std::to_string(max_rows) + " x " + std::to_string(max_cols) +
                         " (opencv-matrix with rows, cols, dt, data): " + why);
  };
  if (!node.isMap()) fail("not a map");
  const cv::FileNode rows = node["rows"], cols = node["cols"];
  if (!rows.isInt() || !cols.isInt()) fail("rows and cols must be integers");
  const int r = static_cast<int>(rows), c = static_cast<int>(cols);
  if (r < 0 || c < 0 || r > max_rows || c > max_cols) {
    fail("found " + std::to_string(r) + " x " + std::to_string(c));
  }
}

void CheckImageDimensions(int64_t width, int64_t height, const std::string& source) {
  if (width < 1 || height < 1 || width > kMaxImageSidePx || height > kMaxImageSidePx ||
      width * height > kMaxImagePixels) {
    throw InputError(source, "image size",
                     "the header says " + std::to_string(width) + " x " + std::to_string(height) +
                         "; romunect reads images of 1 to " + std::to_string(kMaxImageSidePx) + " pixels a side and " +
                         "at most " + std::to_string(kMaxImagePixels) + " pixels");
  }
}

}  // namespace romunect
