#include "dcslam/datasets/text_reader.hpp"

#include <zlib.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "dcslam/core/errors.hpp"

namespace dcslam {

namespace {

// Bytes read from the file, and decompressed, at a time.
constexpr std::size_t kBlockSize = 64 * 1024;

bool is_gzip_start(const unsigned char* bytes, std::size_t size) {
  return size >= 2 && bytes[0] == 0x1f && bytes[1] == 0x8b;
}

}  // namespace

// The file, and for a gzip file the inflate state. zlib's gz* functions are not used: they
// ignore data after the gzip stream and cannot say where a line with a NUL byte ends.
struct TextReader::Source {
  std::FILE* file = nullptr;
  bool gzip = false;
  z_stream stream{};
  bool stream_open = false;
  // Inside a gzip member (false between members and at the end of the last one).
  bool in_member = false;
  std::vector<unsigned char> input = std::vector<unsigned char>(kBlockSize);
  // Bytes of `input` not yet handed on (the start of a plain file, read to detect gzip).
  std::size_t plain_pending = 0;

  ~Source() {
    if (stream_open) inflateEnd(&stream);
    if (file) std::fclose(file);
  }

  std::size_t read(unsigned char* into, std::size_t size, const std::string& path) {
    const std::size_t count = std::fread(into, 1, size, file);
    if (count == 0 && std::ferror(file)) throw ParseError(path + ": cannot read file");
    return count;
  }
};

TextReader::TextReader(const std::string& path)
    : path_(path), source_(std::make_unique<Source>()), block_(kBlockSize) {
  Source& source = *source_;
  source.file = std::fopen(path.c_str(), "rb");
  if (!source.file) throw ParseError(path + ": cannot open file");
  const std::size_t count = source.read(source.input.data(), source.input.size(), path_);
  source.gzip = is_gzip_start(source.input.data(), count);
  if (!source.gzip) {
    source.plain_pending = count;
    return;
  }
  // 16 + MAX_WBITS: a gzip wrapper, not a raw zlib stream.
  if (inflateInit2(&source.stream, 16 + MAX_WBITS) != Z_OK)
    throw ParseError(path + ": cannot start gzip decompression");
  source.stream_open = true;
  source.in_member = true;
  source.stream.next_in = source.input.data();
  source.stream.avail_in = static_cast<uInt>(count);
}

TextReader::~TextReader() = default;

std::string TextReader::where() const { return path_ + ":" + std::to_string(line_number_); }

bool TextReader::fill() {
  Source& source = *source_;
  block_begin_ = block_end_ = 0;
  if (!source.gzip) {
    if (source.plain_pending > 0) {
      std::copy_n(source.input.begin(), source.plain_pending, block_.begin());
      block_end_ = source.plain_pending;
      source.plain_pending = 0;
    } else {
      block_end_ = source.read(reinterpret_cast<unsigned char*>(block_.data()), block_.size(), path_);
    }
    return block_end_ > 0;
  }
  z_stream& stream = source.stream;
  for (;;) {
    if (stream.avail_in == 0) {
      const std::size_t count = source.read(source.input.data(), source.input.size(), path_);
      if (count == 0) {
        if (source.in_member)
          throw ParseError(path_ + ": truncated gzip stream (it ends in line " +
                           std::to_string(line_number_ + 1) + ")");
        return false;
      }
      stream.next_in = source.input.data();
      stream.avail_in = static_cast<uInt>(count);
    }
    if (!source.in_member) {
      // gzip allows several members one after the other; anything else after a member is
      // not part of the file's text.
      if (stream.next_in[0] != 0x1f)
        throw ParseError(path_ + ": trailing data after the gzip stream (after line " +
                         std::to_string(line_number_) + ")");
      inflateReset(&stream);
      source.in_member = true;
    }
    stream.next_out = reinterpret_cast<Bytef*>(block_.data());
    stream.avail_out = static_cast<uInt>(block_.size());
    const int status = inflate(&stream, Z_NO_FLUSH);
    if (status == Z_STREAM_END) {
      source.in_member = false;
    } else if (status != Z_OK && status != Z_BUF_ERROR) {
      throw ParseError(path_ + ": unreadable gzip stream (" +
                       (stream.msg ? std::string(stream.msg) : "zlib error " + std::to_string(status)) +
                       ", in line " + std::to_string(line_number_ + 1) + ")");
    }
    block_end_ = block_.size() - stream.avail_out;
    if (block_end_ > 0) return true;
  }
}

bool TextReader::next_line(std::string& line) {
  line.clear();
  bool read_anything = false;
  for (;;) {
    if (block_begin_ == block_end_ && !fill()) break;
    read_anything = true;
    const char* begin = block_.data() + block_begin_;
    const std::size_t available = block_end_ - block_begin_;
    const auto* newline = static_cast<const char*>(std::memchr(begin, '\n', available));
    const std::size_t length = newline ? static_cast<std::size_t>(newline - begin) : available;
    if (line.size() + length > kMaxLineLength)
      throw ParseError(path_ + ":" + std::to_string(line_number_ + 1) + ": line longer than " +
                       std::to_string(kMaxLineLength) + " bytes");
    line.append(begin, length);
    block_begin_ += newline ? length + 1 : length;
    if (newline) break;
  }
  if (!read_anything) return false;
  ++line_number_;
  if (!line.empty() && line.back() == '\r') line.pop_back();
  const auto nul = line.find('\0');
  if (nul != std::string::npos)
    throw ParseError(where() + ": NUL byte at column " + std::to_string(nul + 1) +
                     " (a binary file?)");
  return true;
}

std::string excerpt(const std::string& text) {
  std::string out;
  const std::size_t shown = std::min(text.size(), kExcerptLength);
  for (std::size_t i = 0; i < shown; ++i) {
    const auto byte = static_cast<unsigned char>(text[i]);
    if (byte >= 0x20 && byte < 0x7f) {
      out += static_cast<char>(byte);
    } else {
      char escaped[5];
      std::snprintf(escaped, sizeof escaped, "\\x%02x", byte);
      out += escaped;
    }
  }
  if (shown < text.size()) out += "...";
  return out;
}

bool try_parse_number(const std::string& text, double& value) {
  // strtod alone would also take hex floats, "inf" and "nan", and skip leading blanks.
  const bool decimal_characters =
      text.find_first_not_of("0123456789+-.eE") == std::string::npos &&
      text.find_first_of("0123456789") != std::string::npos;
  if (!decimal_characters) return false;
  char* end = nullptr;
  errno = 0;
  value = std::strtod(text.c_str(), &end);
  return *end == '\0' && std::isfinite(value) && errno != ERANGE;
}

double parse_number(const std::string& text, const std::string& where, const std::string& field) {
  double value = 0.0;
  if (!try_parse_number(text, value)) throw not_a_number(text, where, field);
  return value;
}

ParseError field_error(const std::string& where, const std::string& field, const std::string& message) {
  return ParseError(where + ": field '" + field + "': " + message);
}

ParseError not_a_number(const std::string& text, const std::string& where, const std::string& field) {
  return field_error(where, field, "'" + excerpt(text) + "' is not a number");
}

std::int64_t parse_integer(const std::string& text, const std::string& where,
                           const std::string& field) {
  const double value = parse_number(text, where, field);
  if (value != std::floor(value) || std::fabs(value) > 9.0e15)
    throw field_error(where, field, "'" + excerpt(text) + "' is not an integer");
  return static_cast<std::int64_t>(value);
}

std::vector<std::string> split_fields(const std::string& line, char separator) {
  std::vector<std::string> fields;
  std::string::size_type start = 0;
  for (;;) {
    const auto stop = line.find(separator, start);
    fields.push_back(line.substr(start, stop - start));
    if (stop == std::string::npos) break;
    start = stop + 1;
  }
  return fields;
}

std::vector<std::string> split_whitespace(const std::string& line) {
  std::vector<std::string> tokens;
  std::string::size_type start = line.find_first_not_of(" \t");
  while (start != std::string::npos) {
    const auto stop = line.find_first_of(" \t", start);
    tokens.push_back(line.substr(start, stop - start));
    start = line.find_first_not_of(" \t", stop);
  }
  return tokens;
}

namespace {

std::string trimmed(const std::string& text) {
  const auto first = text.find_first_not_of(" \t");
  if (first == std::string::npos) return {};
  return text.substr(first, text.find_last_not_of(" \t") - first + 1);
}

}  // namespace

CsvTable::CsvTable(const std::string& path, const std::vector<std::string>& columns)
    : path_(path), names_(columns), values_(columns.size()) {
  TextReader reader(path);
  std::string line;
  if (!reader.next_line(line)) throw ParseError(path + ":1: empty file (expected a header line)");
  std::vector<std::string> header = split_fields(line, ',');
  for (auto& name : header) name = trimmed(name);
  std::vector<std::size_t> positions;
  for (const auto& name : columns) {
    std::size_t position = 0;
    while (position < header.size() && header[position] != name) ++position;
    if (position == header.size())
      throw field_error(reader.where(), name, "missing column (header is '" +
                        excerpt(line) + "')");
    positions.push_back(position);
  }
  while (reader.next_line(line)) {
    if (trimmed(line).empty()) continue;
    const std::vector<std::string> fields = split_fields(line, ',');
    if (fields.size() != header.size())
      throw ParseError(reader.where() + ": expected " + std::to_string(header.size()) +
                       " fields (" + excerpt(header.front()) + ".." + excerpt(header.back()) + "), found " +
                       std::to_string(fields.size()));
    for (std::size_t i = 0; i < columns.size(); ++i) {
      // The line's place is written only for a bad field (per field it was a third of the reading).
      const std::string text = trimmed(fields[positions[i]]);
      double value = 0.0;
      if (!try_parse_number(text, value)) throw not_a_number(text, reader.where(), columns[i]);
      values_[i].push_back(value);
    }
    line_numbers_.push_back(reader.line_number());
  }
  if (line_numbers_.empty())
    throw ParseError(path + ":" + std::to_string(reader.line_number() + 1) +
                     ": no data rows after the header");
}

std::string CsvTable::where(std::size_t row) const {
  return path_ + ":" + std::to_string(line_numbers_[row]);
}

void CsvTable::require_non_decreasing(std::size_t i) const {
  const std::vector<double>& values = values_[i];
  for (std::size_t row = 1; row < values.size(); ++row)
    if (values[row] < values[row - 1])
      throw field_error(where(row), names_[i], number_text(values[row]) +
                        " goes backwards (previous row has " + number_text(values[row - 1]) + ")");
}

void CsvTable::require_integer(std::size_t i) const {
  const std::vector<double>& values = values_[i];
  for (std::size_t row = 0; row < values.size(); ++row)
    if (values[row] != std::floor(values[row]))
      throw field_error(where(row), names_[i], number_text(values[row]) +
                        " is not an integer");
}

}  // namespace dcslam
