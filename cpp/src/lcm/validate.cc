#include "marionette/lcm/validate.h"

#include <cmath>
#include <cstring>
#include <iterator>

#include "marionette/lcm_bounds.hpp"

namespace marionette::wire {
namespace {

constexpr int kMaxFields = 64;

// Where the walk is: a chain of (field, indices) from the message down, formatted only when a
// refusal needs it ("tasks[2].reference[5]").
struct Path {
  const Path* parent;
  const char* field;
  int num_index = 0;
  int64_t index[kMaxDims] = {};
};

std::string Format(const Path* p) {
  if (p == nullptr) return "";
  std::string s = Format(p->parent);
  if (!s.empty()) s += '.';
  s += p->field;
  for (int k = 0; k < p->num_index; ++k) s += "[" + std::to_string(p->index[k]) + "]";
  return s;
}

std::string Number(double x) {
  char buffer[32];
  std::snprintf(buffer, sizeof(buffer), "%.6g", x);
  return buffer;
}

uint64_t BigEndian(const uint8_t* p, int bytes) {
  switch (bytes) {
    case 8: {
      uint64_t v;
      std::memcpy(&v, p, 8);
      return __builtin_bswap64(v);
    }
    case 4: {
      uint32_t v;
      std::memcpy(&v, p, 4);
      return __builtin_bswap32(v);
    }
    case 2: {
      uint16_t v;
      std::memcpy(&v, p, 2);
      return __builtin_bswap16(v);
    }
    default:
      return p[0];
  }
}

int PrimitiveSize(Kind kind) {
  switch (kind) {
    case Kind::kInt8:
    case Kind::kBoolean:
    case Kind::kByte:
      return 1;
    case Kind::kInt16:
      return 2;
    case Kind::kInt32:
    case Kind::kFloat:
      return 4;
    case Kind::kInt64:
    case Kind::kDouble:
      return 8;
    default:
      return 0;
  }
}

// A primitive as a double (integers are exact up to 2^53, far beyond any declared bound), and as
// an integer for the fields that size arrays.
double AsDouble(Kind kind, const uint8_t* p, int64_t* integer) {
  switch (kind) {
    case Kind::kInt8:
      return static_cast<double>(*integer = static_cast<int8_t>(p[0]));
    case Kind::kInt16:
      return static_cast<double>(*integer = static_cast<int16_t>(BigEndian(p, 2)));
    case Kind::kInt32:
      return static_cast<double>(*integer = static_cast<int32_t>(BigEndian(p, 4)));
    case Kind::kInt64:
      return static_cast<double>(*integer = static_cast<int64_t>(BigEndian(p, 8)));
    case Kind::kFloat: {
      const uint32_t bits = static_cast<uint32_t>(BigEndian(p, 4));
      float f;
      std::memcpy(&f, &bits, sizeof(f));
      return f;
    }
    case Kind::kDouble: {
      const uint64_t bits = BigEndian(p, 8);
      double d;
      std::memcpy(&d, &bits, sizeof(d));
      return d;
    }
    default:
      return static_cast<double>(*integer = p[0]);
  }
}

class Walker {
 public:
  Walker(const uint8_t* data, size_t size, std::optional<int64_t> now_us)
      : data_(data), size_(size), now_us_(now_us) {}

  Verdict verdict;
  size_t pos = 0;

  bool Struct(const StructSchema& s, const Path* parent) {
    // The values of this struct's integer fields, for the dimensions that refer to them
    // (generate_lcm_bounds.py keeps structs under kMaxFields fields).
    int64_t integers[kMaxFields] = {};
    for (int i = 0; i < s.num_fields; ++i) {
      const FieldSchema& f = s.fields[i];
      Path path{parent, f.name};
      if (f.num_dims == 0) {
        if (!Element(f, &path, &integers[i])) return false;
        continue;
      }
      // Count the elements first: each dimension is bounded by its field's maximum (checked when
      // that field was read), all of them together by the bytes left (an element takes at least
      // MinElementSize bytes) — so count * size never overflows and no loop outruns the buffer.
      int64_t dims[kMaxDims] = {};
      bool empty = false;
      for (int d = 0; d < f.num_dims; ++d) {
        dims[d] = f.dims[d].field < 0 ? f.dims[d].size : integers[f.dims[d].field];
        empty = empty || dims[d] == 0;
      }
      if (empty) continue;  // (lcm-gen allocates the outer dimensions: bounded by their @max)
      int64_t count = 1;
      const int64_t element = MinElementSize(f);
      for (int d = 0; d < f.num_dims; ++d) {
        count *= dims[d];  // every partial count is at most the whole
        if (static_cast<uint64_t>(count) > Left() / element) {
          return Fail(Refusal::kPastTheEnd, &path,
                      std::to_string(count) + " elements of at least " + std::to_string(element) +
                          " bytes, " + std::to_string(Left()) + " bytes left");
        }
      }
      if (!Array(f, &path, dims, count)) return false;
    }
    return true;
  }

  size_t Left() const { return size_ - pos; }

  bool Fail(Refusal r, const Path* path, const std::string& what) {
    verdict.refusal = r;
    verdict.detail = Format(path);
    if (!what.empty()) verdict.detail += (verdict.detail.empty() ? "" : ": ") + what;
    return false;
  }

 private:
  int64_t MinElementSize(const FieldSchema& f) const {
    if (f.kind == Kind::kString) return 5;
    if (f.kind == Kind::kStruct) return generated::kStructs[f.type].min_size;
    return PrimitiveSize(f.kind);
  }

  bool Array(const FieldSchema& f, Path* path, const int64_t* dims, int64_t count) {
    const int size = PrimitiveSize(f.kind);
    path->num_index = f.num_dims;
    const auto at = [&](int64_t e) {  // the element's indices, for a refusal ("value[3][6]")
      for (int d = f.num_dims - 1; d >= 0; --d) {
        path->index[d] = e % dims[d];
        e /= dims[d];
      }
    };
    if (size == 0) {  // strings, structs
      for (int64_t e = 0; e < count; ++e) {
        at(e);
        int64_t unused = 0;
        if (!Element(f, path, &unused)) return false;
      }
      return true;
    }
    // Primitives: a tight pass over the bytes (sizes checked by the caller); the first offender,
    // if any, is checked again by Element, which says why.
    if (f.kind == Kind::kDouble && f.ranged) {  // most numbers: references, gains, poses
      const uint8_t* p = data_ + pos;
      for (int64_t e = 0; e < count; ++e, p += 8) {
        const uint64_t bits = BigEndian(p, 8);
        double x;
        std::memcpy(&x, &bits, sizeof(x));
        if (!(x >= f.lo && x <= f.hi)) {
          at(e);
          pos = static_cast<size_t>(p - data_);
          int64_t unused = 0;
          return Element(f, path, &unused);
        }
      }
    } else if (f.ranged || f.kind == Kind::kBoolean) {
      const uint8_t* p = data_ + pos;
      for (int64_t e = 0; e < count; ++e, p += size) {
        int64_t integer = 0;
        const double x = AsDouble(f.kind, p, &integer);
        if ((f.kind == Kind::kBoolean && p[0] > 1) || (f.ranged && !(x >= f.lo && x <= f.hi))) {
          at(e);
          pos = static_cast<size_t>(p - data_);
          return Element(f, path, &integer);
        }
      }
    }
    pos += static_cast<size_t>(count) * size;  // nobody bounds them, or all passed
    return true;
  }

  bool Element(const FieldSchema& f, const Path* path, int64_t* integer) {
    if (f.kind == Kind::kString) return String(f, path);
    if (f.kind == Kind::kStruct) return Struct(generated::kStructs[f.type], path);
    const int size = PrimitiveSize(f.kind);
    if (Left() < static_cast<size_t>(size)) {
      return Fail(Refusal::kPastTheEnd, path,
                  std::to_string(size) + " bytes needed, " + std::to_string(Left()) + " left");
    }
    const uint8_t* p = data_ + pos;
    pos += size;
    const double x = AsDouble(f.kind, p, integer);
    if (f.kind == Kind::kBoolean && p[0] > 1) {
      return Fail(Refusal::kNotBoolean, path, "byte " + std::to_string(p[0]) + " (0 or 1)");
    }
    if (f.sizes_arrays) {
      if (*integer < 0) return Fail(Refusal::kNegativeLength, path, std::to_string(*integer));
      if (*integer > f.max) {
        return Fail(Refusal::kOverMaximum, path,
                    std::to_string(*integer) + " > " + std::to_string(f.max));
      }
    }
    if (f.ranged && !(x >= f.lo && x <= f.hi)) {
      return Fail(Refusal::kOutOfRange, path,
                  Number(x) + " outside [" + Number(f.lo) + ", " + Number(f.hi) + "]");
    }
    if (f.clocked) {
      if (*integer < 0) {  // controller time starts at 0
        return Fail(Refusal::kTimeOutOfRange, path, Number(x * 1e-6) + " s < 0");
      }
      if (now_us_) {
        const double from = static_cast<double>(*now_us_) + 1e6 * f.clock_lo_s;
        const double to = static_cast<double>(*now_us_) + 1e6 * f.clock_hi_s;
        if (!(x >= from && x <= to)) {
          return Fail(Refusal::kTimeOutOfRange, path,
                      Number(x * 1e-6) + " s, the controller's time is " +
                          Number(static_cast<double>(*now_us_) * 1e-6) + " s (accepted: " +
                          Number(f.clock_lo_s) + " to +" + Number(f.clock_hi_s) + " s from it)");
        }
      }
    }
    return true;
  }

  bool String(const FieldSchema& f, const Path* path) {
    if (Left() < 4) {
      return Fail(Refusal::kPastTheEnd, path,
                  "a string length needs 4 bytes, " + std::to_string(Left()) + " left");
    }
    const int64_t length = static_cast<int32_t>(BigEndian(data_ + pos, 4));  // NUL included
    pos += 4;
    if (length < 1) {
      return Fail(Refusal::kNegativeLength, path,
                  "string length " + std::to_string(length) + " (at least 1: the NUL)");
    }
    if (static_cast<uint64_t>(length) > Left()) {
      return Fail(
          Refusal::kPastTheEnd, path,
          "string of " + std::to_string(length) + " bytes, " + std::to_string(Left()) + " left");
    }
    if (data_[pos + length - 1] != 0) {
      return Fail(Refusal::kUnterminatedString, path, "no NUL at its end");
    }
    if (length - 1 > f.maxlen) {
      return Fail(
          Refusal::kOverMaximum, path,
          "string of " + std::to_string(length - 1) + " bytes > " + std::to_string(f.maxlen));
    }
    pos += length;
    return true;
  }

  const uint8_t* data_;
  size_t size_;
  std::optional<int64_t> now_us_;
};

}  // namespace

const char* ToString(Refusal refusal) {
  switch (refusal) {
    case Refusal::kNone:
      return "";
    case Refusal::kWrongType:
      return "wrong type";
    case Refusal::kPastTheEnd:
      return "past the end";
    case Refusal::kNegativeLength:
      return "negative length";
    case Refusal::kOverMaximum:
      return "over maximum";
    case Refusal::kUnterminatedString:
      return "unterminated string";
    case Refusal::kNotBoolean:
      return "not a boolean";
    case Refusal::kOutOfRange:
      return "out of range";
    case Refusal::kTimeOutOfRange:
      return "time out of range";
    case Refusal::kTrailingBytes:
      return "trailing bytes";
  }
  return "?";
}

const StructSchema* FindSchema(std::string_view type_name) {
  for (const StructSchema& s : generated::kStructs) {
    if (type_name == s.name) return &s;
  }
  return nullptr;
}

Verdict Validate(const StructSchema& schema, int64_t fingerprint, const void* data, size_t size,
                 std::optional<int64_t> now_us) {
  const auto* bytes = static_cast<const uint8_t*>(data);
  Walker w(bytes, size, now_us);
  if (size < 8 || static_cast<int64_t>(BigEndian(bytes, 8)) != fingerprint) {
    w.Fail(Refusal::kWrongType, nullptr,
           size < 8 ? std::to_string(size) + " bytes, no fingerprint"
                    : std::string("the fingerprint is not ") + schema.name + "'s");
    return w.verdict;
  }
  w.pos = 8;
  if (!w.Struct(schema, nullptr)) return w.verdict;
  if (w.Left() > 0) {
    w.Fail(
        Refusal::kTrailingBytes, nullptr,
        std::to_string(w.Left()) + " bytes after the " + std::to_string(w.pos) + " of the message");
  }
  return w.verdict;
}

}  // namespace marionette::wire
