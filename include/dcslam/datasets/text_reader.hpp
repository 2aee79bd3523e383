#pragma once
// Line-by-line reading of plain or gzip-compressed text files, and a small CSV table reader
// on top of it. Every error is a ParseError whose message starts with "<file>:<line>:" and
// names the offending field, so a user can open the file at the right place.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "dcslam/core/errors.hpp"

namespace dcslam {

// Reads a plain or gzip text file (detected from its content, not its name) one line at a
// time, holding one line and one 64 KiB block in memory whatever the file's size. Concatenated
// gzip members read as one file. ParseError for a line longer than kMaxLineLength, a NUL byte
// (a binary file), a gzip stream that ends early ("<file>: truncated gzip stream (it ends in
// line N)") and data after the gzip stream.
class TextReader {
 public:
  // The longest line accepted, in bytes, without its line ending: far above any line of the
  // formats read here, and it bounds the memory a broken file (one endless line) can take.
  static constexpr std::size_t kMaxLineLength = 64 * 1024;

  explicit TextReader(const std::string& path);
  ~TextReader();
  TextReader(const TextReader&) = delete;
  TextReader& operator=(const TextReader&) = delete;

  // Reads the next line without its line ending ("\n" or "\r\n"). Returns false at the end.
  bool next_line(std::string& line);

  const std::string& path() const { return path_; }
  // 1-based number of the line last returned by next_line.
  std::int64_t line_number() const { return line_number_; }
  // "<file>:<line>", the prefix of every error message about the current line.
  std::string where() const;

 private:
  struct Source;
  // Refills block_ with the next bytes of the text; false at its end.
  bool fill();

  std::string path_;
  std::unique_ptr<Source> source_;
  std::vector<char> block_;
  std::size_t block_begin_ = 0, block_end_ = 0;
  std::int64_t line_number_ = 0;
};

// The ParseError about one field of a file, "<where>: field '<field>': <message>": the form of
// every reader's field errors.
ParseError field_error(const std::string& where, const std::string& field, const std::string& message);
// Throws field_error(where(), field, fault) when `fault` (an input_checks.hpp message) is not
// empty. `where` is called only then: building the place for every field of every row costs a
// third of a reading.
template <class Where>
void require_no_fault(const std::string& fault, const Where& where, const std::string& field) {
  if (!fault.empty()) throw field_error(where(), field, fault);
}

// Bytes of a file quoted in messages: at most kExcerptLength of them, then "..." when cut;
// bytes that are not printable ASCII as \xNN, so that a message is text whatever the file
// holds and a 10 MB token does not become a 10 MB message.
constexpr std::size_t kExcerptLength = 40;
std::string excerpt(const std::string& text);

// Parses a whole decimal number (digits, sign, point, exponent); throws ParseError "<where>:
// field '<field>': '<excerpt>' is not a number" otherwise (also for inf, nan, hex floats and
// values beyond double's range, which no dataset field may hold).
double parse_number(const std::string& text, const std::string& where, const std::string& field);
// parse_number's test without the message: false where it would throw (value then unspecified).
bool try_parse_number(const std::string& text, double& value);
// The ParseError parse_number throws for `text`.
ParseError not_a_number(const std::string& text, const std::string& where, const std::string& field);
// Same for an integer field: also rejects fractional values.
std::int64_t parse_integer(const std::string& text, const std::string& where,
                           const std::string& field);

// The numeric columns of a comma-separated file with one header line and at least one row.
// Only the requested columns are kept (in the requested order); the header must hold each of
// them, and every row must have as many fields as the header.
class CsvTable {
 public:
  CsvTable(const std::string& path, const std::vector<std::string>& columns);

  const std::string& path() const { return path_; }
  std::size_t rows() const { return line_numbers_.size(); }
  // Values of the i-th requested column, one per row.
  const std::vector<double>& column(std::size_t i) const { return values_[i]; }
  const std::string& column_name(std::size_t i) const { return names_[i]; }
  // "<file>:<line>" of a row, for errors found after parsing (e.g. times going backwards).
  std::string where(std::size_t row) const;

  // Throws ParseError naming the first row whose value in column i is below the previous one.
  void require_non_decreasing(std::size_t i) const;
  // Throws ParseError naming the first row whose value in column i is not an integer.
  void require_integer(std::size_t i) const;

 private:
  std::string path_;
  std::vector<std::string> names_;
  std::vector<std::vector<double>> values_;
  std::vector<std::int64_t> line_numbers_;
};

// Splits a line on a single-character separator ("a,,b" gives three fields).
std::vector<std::string> split_fields(const std::string& line, char separator);
// Splits a line on runs of blanks (spaces and tabs), dropping empty tokens.
std::vector<std::string> split_whitespace(const std::string& line);

}  // namespace dcslam
