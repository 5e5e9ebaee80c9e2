#pragma once
/// Signed command messages (lcmtypes/README.md, "Signed messages"): with a shared key, a sender
/// appends a 52-byte trailer to the LCM-encoded message, so that lcm-spy and lcm-logger still
/// decode it as the plain type (LCM decoders stop at the message's end):
///
///   offset  bytes  field
///        0      4  magic "MSIG"
///        4      8  sender: random, drawn once per sending process
///       12      8  sequence: big-endian, the sender's wall clock [us], strictly increasing
///       20     32  tag = HMAC-SHA256(key, "marionette-lcm-signature-v1" NUL channel NUL
///                                      message sender sequence)
///
/// The receiver refuses a message without a trailer, with a wrong tag (the key, the bytes or the
/// channel differ: a message cannot be moved to another channel), with a sequence not above the
/// last one it took from that sender on that channel (a replay), or stamped more than the
/// window away from its own wall clock (a replay recorded before it started). HMAC and random
/// bytes come from OpenSSL's libcrypto.

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <map>
#include <memory>
#include <string>
#include <utility>

namespace marionette::wire {

inline constexpr size_t kTrailerSize = 52;
inline constexpr char kTrailerMagic[] = "MSIG";  // 4 bytes, no NUL on the wire
inline constexpr double kSignatureWindowS = 10.0;

/// A shared key: the bytes of a file (trailing whitespace removed), at least 32 of them, readable
/// by its owner only. Throws std::runtime_error saying what is wrong and what to do.
std::string LoadKey(const std::string& path);

/// HMAC-SHA256 with one key, of the concatenation of byte ranges (OpenSSL's EVP_MAC, keyed once).
class Hmac {
 public:
  explicit Hmac(const std::string& key);
  ~Hmac();
  Hmac(const Hmac&) = delete;
  Hmac& operator=(const Hmac&) = delete;
  /// The 32-byte tag of the concatenated `parts`.
  std::string Digest(std::initializer_list<std::pair<const void*, size_t>> parts) const;

 private:
  struct Context;
  std::unique_ptr<Context> context_;
};

/// Whether the last kTrailerSize bytes of `data` are a trailer (its magic).
bool HasTrailer(const void* data, size_t size);

class Signer {
 public:
  explicit Signer(std::string key);
  /// `message` (LCM-encoded) followed by its trailer for `channel`.
  std::string Sign(const std::string& channel, const void* message, size_t size, int64_t now_us);
  uint64_t sender() const { return sender_; }

 private:
  Hmac mac_;
  uint64_t sender_ = 0;
  uint64_t last_sequence_ = 0;
};

enum class SignatureCheck { kAccepted, kUnsigned, kBadSignature, kReplayed, kStale };
/// The counted name of a refusal: "unsigned", "bad signature", "replayed", "stale signature".
const char* ToString(SignatureCheck check);

class Verifier {
 public:
  explicit Verifier(std::string key, double window_s = kSignatureWindowS);
  /// Checks the trailer of `data` received on `channel` at wall-clock `now_us`; on kAccepted,
  /// the message is the first `*message_size` bytes. `detail` says why on a refusal.
  SignatureCheck Verify(const std::string& channel, const void* data, size_t size, int64_t now_us,
                        size_t* message_size, std::string* detail);

 private:
  Hmac mac_;
  double window_s_;
  std::map<std::pair<uint64_t, std::string>, uint64_t> last_;  // (sender, channel) -> sequence
};

}  // namespace marionette::wire
