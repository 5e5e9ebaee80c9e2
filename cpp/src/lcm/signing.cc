#include "marionette/lcm/signing.h"

#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/params.h>
#include <openssl/rand.h>
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace marionette::wire {
namespace {

constexpr char kDomain[] = "marionette-lcm-signature-v1";  // with its NUL
constexpr size_t kMinKeyBytes = 32;
constexpr size_t kMaxSenders = 4096;  // (sender, channel) pairs remembered

void PutBigEndian(uint64_t v, uint8_t* out) {
  for (int i = 7; i >= 0; --i, v >>= 8) out[i] = static_cast<uint8_t>(v & 0xff);
}

uint64_t GetBigEndian(const uint8_t* p) {
  uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

// The tag of `message` on `channel` from `sender_and_sequence` (the trailer's 16 bytes).
std::string Tag(const Hmac& mac, const std::string& channel, const void* message, size_t size,
                const uint8_t* sender_and_sequence) {
  return mac.Digest({{kDomain, sizeof(kDomain)},
                     {channel.data(), channel.size() + 1},  // with its NUL
                     {message, size},
                     {sender_and_sequence, 16}});
}

}  // namespace

std::string LoadKey(const std::string& path) {
  struct stat st {};
  if (stat(path.c_str(), &st) != 0) {
    throw std::runtime_error(
        "key file '" + path +
        "' not found (create one: openssl rand -hex 32 > FILE; chmod 600 FILE)");
  }
  if ((st.st_mode & 077) != 0) {
    throw std::runtime_error("key file '" + path +
                             "' is readable by others: chmod 600 it (a shared key is a secret)");
  }
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  std::string key = bytes.str();
  while (!key.empty() && std::isspace(static_cast<unsigned char>(key.back()))) key.pop_back();
  if (!in || key.size() < kMinKeyBytes) {
    throw std::runtime_error("key file '" + path + "' holds " + std::to_string(key.size()) +
                             " bytes, at least " + std::to_string(kMinKeyBytes) +
                             " are needed (openssl rand -hex 32 > FILE)");
  }
  return key;
}

// A context keyed once; each digest works on a copy of it (EVP_MAC_CTX_dup), so the key's
// padding blocks are hashed once, not per message.
struct Hmac::Context {
  EVP_MAC* mac = nullptr;
  EVP_MAC_CTX* keyed = nullptr;
};

Hmac::Hmac(const std::string& key) : context_(std::make_unique<Context>()) {
  char digest[] = "SHA256";
  const OSSL_PARAM params[] = {OSSL_PARAM_construct_utf8_string("digest", digest, 0),
                               OSSL_PARAM_construct_end()};
  context_->mac = EVP_MAC_fetch(nullptr, "HMAC", nullptr);
  context_->keyed = context_->mac ? EVP_MAC_CTX_new(context_->mac) : nullptr;
  if (context_->keyed == nullptr ||
      EVP_MAC_init(context_->keyed, reinterpret_cast<const unsigned char*>(key.data()), key.size(),
                   params) != 1) {
    EVP_MAC_CTX_free(context_->keyed);
    EVP_MAC_free(context_->mac);
    throw std::runtime_error("OpenSSL: cannot set up HMAC-SHA256");
  }
}

Hmac::~Hmac() {
  EVP_MAC_CTX_free(context_->keyed);
  EVP_MAC_free(context_->mac);
}

std::string Hmac::Digest(std::initializer_list<std::pair<const void*, size_t>> parts) const {
  EVP_MAC_CTX* ctx = EVP_MAC_CTX_dup(context_->keyed);
  unsigned char out[EVP_MAX_MD_SIZE];
  size_t out_size = 0;
  bool ok = ctx != nullptr;
  for (const auto& [data, size] : parts) {
    ok = ok && EVP_MAC_update(ctx, static_cast<const unsigned char*>(data), size) == 1;
  }
  ok = ok && EVP_MAC_final(ctx, out, &out_size, sizeof(out)) == 1;
  EVP_MAC_CTX_free(ctx);
  if (!ok || out_size != 32) throw std::runtime_error("OpenSSL: HMAC-SHA256 failed");
  return std::string(reinterpret_cast<const char*>(out), out_size);
}

bool HasTrailer(const void* data, size_t size) {
  return size >= kTrailerSize &&
         std::memcmp(static_cast<const char*>(data) + size - kTrailerSize, kTrailerMagic, 4) == 0;
}

Signer::Signer(std::string key) : mac_(key) {
  uint8_t id[8];
  if (RAND_bytes(id, sizeof(id)) != 1) throw std::runtime_error("OpenSSL RAND_bytes failed");
  sender_ = GetBigEndian(id);
}

std::string Signer::Sign(const std::string& channel, const void* message, size_t size,
                         int64_t now_us) {
  last_sequence_ = std::max<uint64_t>(last_sequence_ + 1, static_cast<uint64_t>(now_us));
  uint8_t trailer[kTrailerSize];
  std::memcpy(trailer, kTrailerMagic, 4);
  PutBigEndian(sender_, trailer + 4);
  PutBigEndian(last_sequence_, trailer + 12);
  const std::string tag = Tag(mac_, channel, message, size, trailer + 4);
  std::memcpy(trailer + 20, tag.data(), 32);
  std::string out(static_cast<const char*>(message), size);
  out.append(reinterpret_cast<const char*>(trailer), kTrailerSize);
  return out;
}

const char* ToString(SignatureCheck check) {
  switch (check) {
    case SignatureCheck::kAccepted:
      return "";
    case SignatureCheck::kUnsigned:
      return "unsigned";
    case SignatureCheck::kBadSignature:
      return "bad signature";
    case SignatureCheck::kReplayed:
      return "replayed";
    case SignatureCheck::kStale:
      return "stale signature";
  }
  return "?";
}

Verifier::Verifier(std::string key, double window_s) : mac_(key), window_s_(window_s) {}

SignatureCheck Verifier::Verify(const std::string& channel, const void* data, size_t size,
                                int64_t now_us, size_t* message_size, std::string* detail) {
  if (!HasTrailer(data, size)) {
    *detail = "no signature: this controller takes signed commands only (MARIONETTE_KEY)";
    return SignatureCheck::kUnsigned;
  }
  const size_t n = size - kTrailerSize;
  const auto* trailer = static_cast<const uint8_t*>(data) + n;
  const std::string tag = Tag(mac_, channel, data, n, trailer + 4);
  if (CRYPTO_memcmp(tag.data(), trailer + 20, 32) != 0) {
    *detail = "the tag does not match (another key, altered bytes, or another channel)";
    return SignatureCheck::kBadSignature;
  }
  const uint64_t sender = GetBigEndian(trailer + 4);
  const uint64_t sequence = GetBigEndian(trailer + 12);
  const double skew_s = (static_cast<double>(sequence) - static_cast<double>(now_us)) * 1e-6;
  if (!(std::abs(skew_s) <= window_s_)) {
    char buffer[160];
    std::snprintf(buffer, sizeof(buffer),
                  "signed %.1f s %s this clock (at most %.0f s: replayed, or the clocks of the "
                  "machines disagree)",
                  std::abs(skew_s), skew_s < 0 ? "before" : "after", window_s_);
    *detail = buffer;
    return SignatureCheck::kStale;
  }
  const auto key = std::make_pair(sender, channel);
  const auto it = last_.find(key);
  if (it != last_.end() && sequence <= it->second) {
    *detail = "sequence " + std::to_string(sequence) + " after " + std::to_string(it->second) +
              " from the same sender";
    return SignatureCheck::kReplayed;
  }
  if (it == last_.end() && last_.size() >= kMaxSenders) {
    // Forget the sender heard from longest ago (its messages are beyond the window by then).
    auto oldest = last_.begin();
    for (auto i = last_.begin(); i != last_.end(); ++i)
      if (i->second < oldest->second) oldest = i;
    last_.erase(oldest);
  }
  last_[key] = sequence;
  *message_size = n;
  return SignatureCheck::kAccepted;
}

}  // namespace marionette::wire
