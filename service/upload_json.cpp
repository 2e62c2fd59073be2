#include "upload_json.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdint>
#include <optional>

namespace spokemesh::service {
namespace {

using json = nlohmann::json;

// The SAX handler: one event per token, in document order. Every handler returns
// false to stop the parse at the first error, which it records in `error`.
class UploadSax final : public nlohmann::json_sax<json> {
 public:
  UploadSax(const Limits& limits, UploadHeader& header, std::vector<double>& coords, std::vector<double>& weights,
            MemoryBudget::Charge* charge, const MemoryBudget* budget)
      : weights_(weights),
        charge_(charge),
        budget_(budget),
        max_points_(limits.max_points),
        max_values_(limits.max_points * static_cast<std::uint64_t>(std::max(2, limits.max_dimension))),
        header_(header),
        coords_(coords) {}

  Status error = Status::ok();
  // After a successful parse: checks what only the whole body can tell.
  Status finish() {
    header_.weighted = saw_weights_;
    if (saw_weights_ && weights_.empty()) return invalid_argument("weights: expected one number per point");
    if (!saw_points_ && !saw_coordinates_) {
      return invalid_argument("body: expected \"points\" or \"dimension\" and \"coordinates\"");
    }
    if (saw_points_) {
      if (rows_ == 0) return invalid_argument("points: expected a non-empty array of points");
      header_.dimension = static_cast<std::int64_t>(row_width_);
      header_.count = static_cast<std::int64_t>(rows_);
      return Status::ok();
    }
    if (!dimension_) return invalid_argument("dimension: a positive integer is required with \"coordinates\"");
    const std::uint64_t d = *dimension_;
    if (d < 2 || d > static_cast<std::uint64_t>(kMaxApproxDimension)) {
      return invalid_argument("dimension: " + std::to_string(d) + " is not supported; it must be between 2 and " +
                              std::to_string(kMaxApproxDimension));
    }
    if (coords_.size() % d != 0) {
      return invalid_argument("coordinates: " + std::to_string(coords_.size()) +
                              " numbers are not a multiple of dimension " + std::to_string(d));
    }
    header_.dimension = static_cast<std::int64_t>(d);
    header_.count = static_cast<std::int64_t>(coords_.size() / d);
    return Status::ok();
  }

  bool null() override { return scalar("null"); }
  bool boolean(bool v) override { return scalar(v ? "true" : "false"); }
  bool number_integer(number_integer_t v) override { return number(static_cast<double>(v), std::to_string(v)); }
  bool number_unsigned(number_unsigned_t v) override {
    if (depth_ == 1 && key_ == "dimension") {
      dimension_ = v;
      return true;
    }
    return number(static_cast<double>(v), std::to_string(v));
  }
  bool number_float(number_float_t v, const string_t& text) override { return number(v, text); }
  bool string(string_t& v) override {
    if (depth_ == 1 && key_ == "display_name") {
      header_.display_name = std::move(v);
      return true;
    }
    return scalar(json(v).dump(-1, ' ', false, json::error_handler_t::replace));
  }
  bool binary(binary_t&) override { return scalar("binary data"); }

  bool start_object(std::size_t) override { return open(/*array=*/false); }
  bool end_object() override { return close(); }
  bool start_array(std::size_t) override { return open(/*array=*/true); }
  bool end_array() override { return close(); }
  bool key(string_t& k) override {
    key_ = std::move(k);
    return true;
  }

  bool parse_error(std::size_t position, const std::string&, const nlohmann::detail::exception& e) override {
    // e.what() already names the byte; keep nlohmann's own wording after our prefix.
    return fail(invalid_argument("body: invalid JSON near byte " + std::to_string(position) + ": " + e.what()));
  }

 private:
  enum class Field { kNone, kPoints, kCoordinates, kWeights, kBox, kSkipped };

  bool fail(Status s) {
    if (error.is_ok()) error = std::move(s);
    return false;
  }
  // Where a value at the current depth sits, for error messages.
  std::string where() const {
    if (field_ == Field::kPoints) {
      return depth_ == 2 ? "points[" + std::to_string(rows_) + "]"
                         : "points[" + std::to_string(rows_) + "][" + std::to_string(in_row_) + "]";
    }
    if (field_ == Field::kCoordinates) return "coordinates[" + std::to_string(coords_.size()) + "]";
    if (field_ == Field::kWeights) return "weights[" + std::to_string(weights_.size()) + "]";
    if (field_ == Field::kBox) return "periodic_box[" + std::to_string(header_.periodic_box.size()) + "]";
    return key_;
  }
  bool push(double v) {
    if (coords_.size() >= max_values_) {
      return fail(resource_exhausted("body: more than " + std::to_string(max_values_) +
                                     " coordinates (this server's limits --max-points times --max-dimension)"));
    }
    return charged_push(coords_, v, "parsing the uploaded coordinates");
  }
  // Appends v to `to`, growing it here as the vector would, so that the charge follows
  // the capacity (RESOURCE_EXHAUSTED when the budget cannot take it).
  bool charged_push(std::vector<double>& to, double v, const char* what) {
    if (to.size() == to.capacity() && charge_ != nullptr) {
      const std::size_t next = std::max<std::size_t>(1024, 2 * to.capacity());
      const std::uint64_t more = (next - to.capacity()) * sizeof(double);
      if (!charge_->grow(more)) return fail(budget_->over_budget(what, more));
      to.reserve(next);
    }
    to.push_back(v);
    return true;
  }

  bool number(double v, const std::string& text) {
    if (depth_ == 3 && field_ == Field::kPoints) {
      ++in_row_;
      return push(v);
    }
    if (depth_ == 2 && field_ == Field::kCoordinates) return push(v);
    if (depth_ == 2 && field_ == Field::kWeights) {
      if (weights_.size() >= max_points_) {
        return fail(
            resource_exhausted("weights: more than this server's limit --max-points=" + std::to_string(max_points_)));
      }
      return charged_push(weights_, v, "parsing the uploaded weights");
    }
    if (depth_ == 2 && field_ == Field::kBox) {
      if (header_.periodic_box.size() >= 2 * static_cast<std::size_t>(kMaxApproxDimension)) {
        return fail(invalid_argument("periodic_box: more than " + std::to_string(2 * kMaxApproxDimension) + " values"));
      }
      header_.periodic_box.push_back(v);
      return true;
    }
    return scalar(text);
  }
  // A scalar where it is not a coordinate: fine under an unknown key, an error in a
  // known field.
  bool scalar(const std::string& text) {
    if (depth_ == 0) return fail(invalid_argument("body: expected a JSON object"));
    if (field_ == Field::kSkipped) return true;
    if (field_ == Field::kPoints) {
      return fail(invalid_argument(
          where() + (depth_ == 2 ? ": expected an array of coordinates, got " : ": expected a number, got ") +
          text.substr(0, 40)));
    }
    if (field_ == Field::kCoordinates || field_ == Field::kWeights || field_ == Field::kBox) {
      return fail(invalid_argument(where() + ": expected a number, got " + text.substr(0, 40)));
    }
    // depth 1: the value of a top-level key.
    if (key_ == "display_name") return fail(invalid_argument("display_name: expected a string"));
    if (key_ == "dimension") {
      return fail(invalid_argument("dimension: a positive integer is required with \"coordinates\""));
    }
    if (key_ == "points") return fail(invalid_argument("points: expected a non-empty array of points"));
    if (key_ == "coordinates") return fail(invalid_argument("coordinates: expected a flat array of numbers"));
    if (key_ == "weights") return fail(invalid_argument("weights: expected a flat array of numbers, one per point"));
    if (key_ == "periodic_box") {
      return fail(invalid_argument("periodic_box: expected a flat array LO_1..LO_d, HI_1..HI_d"));
    }
    return true;  // an unknown key's scalar
  }

  bool open(bool array) {
    if (depth_ >= kMaxUploadJsonDepth) {
      const std::string at = field_ == Field::kPoints || field_ == Field::kCoordinates ? where() : "body";
      return fail(invalid_argument(at + ": nested deeper than an upload's " + std::to_string(kMaxUploadJsonDepth) +
                                   " levels (expected a number)"));
    }
    if (depth_ == 0) {
      if (array) return fail(invalid_argument("body: expected a JSON object"));
      depth_ = 1;
      return true;
    }
    if (depth_ == 1) {
      if (key_ == "points" || key_ == "coordinates") {
        if (!array) return scalar("an object");
        if (saw_points_ || saw_coordinates_) {
          return fail(invalid_argument("body: give \"points\" or \"coordinates\", not both"));
        }
        field_ = key_ == "points" ? Field::kPoints : Field::kCoordinates;
        (field_ == Field::kPoints ? saw_points_ : saw_coordinates_) = true;
      } else if (key_ == "weights" || key_ == "periodic_box") {
        if (!array) return scalar("an object");
        bool& seen = key_ == "weights" ? saw_weights_ : saw_box_;
        if (seen) return fail(invalid_argument(key_ + ": given twice"));
        seen = true;
        field_ = key_ == "weights" ? Field::kWeights : Field::kBox;
      } else if (key_ == "display_name" || key_ == "dimension") {
        return scalar(array ? "an array" : "an object");
      } else {
        field_ = Field::kSkipped;
      }
      depth_ = 2;
      return true;
    }
    // depth 2: a point of "points", or nesting under a skipped key.
    if (field_ == Field::kPoints) {
      if (!array) return fail(invalid_argument(where() + ": expected an array of coordinates, got an object"));
      in_row_ = 0;
    } else if (field_ == Field::kCoordinates || field_ == Field::kWeights || field_ == Field::kBox) {
      return fail(invalid_argument(where() + ": expected a number, got " + (array ? "an array" : "an object")));
    }
    depth_ = 3;
    return true;
  }

  bool close() {
    if (depth_ == 3 && field_ == Field::kPoints) {
      if (rows_ == 0) {
        row_width_ = in_row_;
      } else if (in_row_ != row_width_) {
        return fail(invalid_argument("points[" + std::to_string(rows_) + "]: " + std::to_string(in_row_) +
                                     " coordinates, but points[0] has " + std::to_string(row_width_)));
      }
      if (++rows_ > max_points_) {
        return fail(
            resource_exhausted("points: more than this server's limit --max-points=" + std::to_string(max_points_)));
      }
    }
    if (depth_ == 2) field_ = Field::kNone;
    --depth_;
    return true;
  }

  std::vector<double>& weights_;
  MemoryBudget::Charge* charge_;
  const MemoryBudget* budget_;
  const std::uint64_t max_points_;
  const std::uint64_t max_values_;
  UploadHeader& header_;
  std::vector<double>& coords_;
  int depth_ = 0;
  std::string key_;  // the last top-level key
  Field field_ = Field::kNone;
  bool saw_points_ = false, saw_coordinates_ = false, saw_weights_ = false, saw_box_ = false;
  std::size_t rows_ = 0, row_width_ = 0, in_row_ = 0;
  std::optional<std::uint64_t> dimension_;
};

}  // namespace

Status read_upload_json(std::string_view body, const Limits& limits, UploadHeader& header, std::vector<double>& coords,
                        std::vector<double>& weights, MemoryBudget::Charge* charge, const MemoryBudget* budget) {
  if (charge != nullptr && budget == nullptr) return internal_error("read_upload_json: a charge needs its budget");
  UploadSax sax(limits, header, coords, weights, charge, budget);
  bool parsed = false;
  try {
    parsed = json::sax_parse(body.begin(), body.end(), &sax, json::input_format_t::json, /*strict=*/true);
  } catch (const json::exception& e) {  // defensive: the SAX path reports through parse_error
    return invalid_argument(std::string("body: invalid JSON: ") + e.what());
  }
  if (!sax.error.is_ok()) return sax.error;
  if (!parsed) return invalid_argument("body: invalid JSON");
  return sax.finish();
}

}  // namespace spokemesh::service
