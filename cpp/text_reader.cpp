#include "dcslam/text_reader.hpp"

#include <zlib.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>

#include "dcslam/errors.hpp"

namespace dcslam {

struct TextReader::GzFile {
  gzFile handle = nullptr;
  ~GzFile() {
    if (handle) gzclose(handle);
  }
};

TextReader::TextReader(const std::string& path) : path_(path), file_(std::make_unique<GzFile>()) {
  // gzopen reads plain files transparently, so one code path serves both kinds.
  file_->handle = gzopen(path.c_str(), "rb");
  if (!file_->handle) throw ParseError(path + ": cannot open file");
}

TextReader::~TextReader() = default;

std::string TextReader::where() const { return path_ + ":" + std::to_string(line_number_); }

bool TextReader::next_line(std::string& line) {
  line.clear();
  char buffer[4096];
  bool read_anything = false;
  for (;;) {
    const char* got = gzgets(file_->handle, buffer, sizeof buffer);
    if (got) {
      read_anything = true;
      line += got;
      if (!line.empty() && line.back() == '\n') break;
    }
    // No newline yet: either a long line (keep reading) or the end of the data, where zlib
    // reports a stream that stopped before its end as Z_BUF_ERROR.
    int error_code = Z_OK;
    const char* message = gzerror(file_->handle, &error_code);
    if (error_code == Z_BUF_ERROR) throw ParseError(path_ + ": truncated gzip stream");
    if (error_code != Z_OK) throw ParseError(path_ + ": unreadable gzip stream (" + message + ")");
    if (!got || gzeof(file_->handle)) break;
  }
  if (!read_anything) return false;
  if (!line.empty() && line.back() == '\n') line.pop_back();
  if (!line.empty() && line.back() == '\r') line.pop_back();
  ++line_number_;
  return true;
}

double parse_number(const std::string& text, const std::string& where, const std::string& field) {
  const char* begin = text.c_str();
  char* end = nullptr;
  errno = 0;
  const double value = std::strtod(begin, &end);
  while (end && (*end == ' ' || *end == '\t')) ++end;
  if (text.empty() || end == begin || *end != '\0' || !std::isfinite(value) || errno == ERANGE)
    throw ParseError(where + ": field '" + field + "': '" + text + "' is not a number");
  return value;
}

std::int64_t parse_integer(const std::string& text, const std::string& where,
                           const std::string& field) {
  const double value = parse_number(text, where, field);
  if (value != std::floor(value) || std::fabs(value) > 9.0e15)
    throw ParseError(where + ": field '" + field + "': '" + text + "' is not an integer");
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
      throw ParseError(reader.where() + ": field '" + name + "': missing column (header is '" +
                       line + "')");
    positions.push_back(position);
  }
  while (reader.next_line(line)) {
    if (trimmed(line).empty()) continue;
    const std::vector<std::string> fields = split_fields(line, ',');
    if (fields.size() != header.size())
      throw ParseError(reader.where() + ": expected " + std::to_string(header.size()) +
                       " fields (" + header.front() + ".." + header.back() + "), found " +
                       std::to_string(fields.size()));
    for (std::size_t i = 0; i < columns.size(); ++i)
      values_[i].push_back(parse_number(trimmed(fields[positions[i]]), reader.where(), columns[i]));
    line_numbers_.push_back(reader.line_number());
  }
}

std::string CsvTable::where(std::size_t row) const {
  return path_ + ":" + std::to_string(line_numbers_[row]);
}

void CsvTable::require_non_decreasing(std::size_t i) const {
  const std::vector<double>& values = values_[i];
  for (std::size_t row = 1; row < values.size(); ++row)
    if (values[row] < values[row - 1])
      throw ParseError(where(row) + ": field '" + names_[i] + "': " + std::to_string(values[row]) +
                       " goes backwards (previous row has " + std::to_string(values[row - 1]) +
                       ")");
}

void CsvTable::require_integer(std::size_t i) const {
  const std::vector<double>& values = values_[i];
  for (std::size_t row = 0; row < values.size(); ++row)
    if (values[row] != std::floor(values[row]))
      throw ParseError(where(row) + ": field '" + names_[i] + "': " +
                       std::to_string(values[row]) + " is not an integer");
}

}  // namespace dcslam
