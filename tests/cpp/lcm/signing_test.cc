// Signed command messages: HMAC-SHA256 against RFC 4231's test vectors, then the trailer's checks
// (tag, channel binding, replays, freshness) and the key file's.
#include "marionette/lcm/signing.h"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace marionette::wire {
namespace {

std::string Hex(const std::string& bytes) {
  static const char* digits = "0123456789abcdef";
  std::string out;
  for (unsigned char c : bytes) out += {digits[c >> 4], digits[c & 15]};
  return out;
}

std::string Sha256Hmac(const std::string& key, const std::string& data) {
  return Hex(Hmac(key).Digest({{data.data(), data.size()}}));
}

TEST(SigningTest, HmacMatchesRfc4231) {
  // RFC 4231 section 4, test cases 1, 2, 3 and 6 (HMAC-SHA-256).
  EXPECT_EQ(Sha256Hmac(std::string(20, '\x0b'), "Hi There"),
            "b0344c61d8db38535ca8afceaf0bf12b881dc200c9833da726e9376c2e32cff7");
  EXPECT_EQ(Sha256Hmac("Jefe", "what do ya want for nothing?"),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
  EXPECT_EQ(Sha256Hmac(std::string(20, '\xaa'), std::string(50, '\xdd')),
            "773ea91e36800e46854db8ebd09181a72959098b3ef8c122d9635514ced565fe");
  EXPECT_EQ(Sha256Hmac(std::string(131, '\xaa'),
                       "Test Using Larger Than Block-Size Key - Hash Key First"),
            "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54");
  // Parts are concatenated.
  const Hmac mac("Jefe");
  const std::string a = "what do ya ", b = "want for nothing?";
  EXPECT_EQ(Hex(mac.Digest({{a.data(), a.size()}, {b.data(), b.size()}})),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
}

constexpr int64_t kNow = 1'700'000'000'000'000;  // [us]
const std::string kKey(32, 'k');
const std::string kMessage = "an LCM-encoded message";

SignatureCheck Verify(Verifier& v, const std::string& channel, const std::string& data,
                      int64_t now_us = kNow, size_t* size = nullptr) {
  size_t n = 0;
  std::string detail;
  const SignatureCheck c = v.Verify(channel, data.data(), data.size(), now_us, &n, &detail);
  EXPECT_EQ(c == SignatureCheck::kAccepted, detail.empty()) << detail;
  if (size) *size = n;
  return c;
}

TEST(SigningTest, SignedMessagesPassOnceOnTheirChannel) {
  Signer signer(kKey);
  Verifier verifier(kKey);
  const std::string signed_message = signer.Sign("COMMAND", kMessage.data(), kMessage.size(), kNow);
  ASSERT_EQ(signed_message.size(), kMessage.size() + kTrailerSize);
  EXPECT_EQ(signed_message.substr(0, kMessage.size()), kMessage);  // LCM decoders stop there
  EXPECT_TRUE(HasTrailer(signed_message.data(), signed_message.size()));
  size_t size = 0;
  EXPECT_EQ(Verify(verifier, "COMMAND", signed_message, kNow, &size), SignatureCheck::kAccepted);
  EXPECT_EQ(size, kMessage.size());
  EXPECT_EQ(Verify(verifier, "COMMAND", signed_message), SignatureCheck::kReplayed);
  // Moved to another channel: the tag binds the channel's name.
  EXPECT_EQ(Verify(verifier, "SIM_COMMAND", signed_message), SignatureCheck::kBadSignature);
  // The next message of the sender passes; sequences are per channel.
  const std::string next = signer.Sign("COMMAND", kMessage.data(), kMessage.size(), kNow);
  EXPECT_EQ(Verify(verifier, "COMMAND", next), SignatureCheck::kAccepted);
  const std::string other = signer.Sign("CONTROLLER_SPEC", kMessage.data(), kMessage.size(), kNow);
  EXPECT_EQ(Verify(verifier, "CONTROLLER_SPEC", other), SignatureCheck::kAccepted);
}

TEST(SigningTest, AlteredUnsignedForeignAndStaleMessagesAreRefused) {
  Signer signer(kKey);
  Verifier verifier(kKey);
  const std::string good = signer.Sign("COMMAND", kMessage.data(), kMessage.size(), kNow);
  for (size_t i = 0; i < good.size(); ++i) {  // every byte, the trailer's too
    std::string bad = good;
    bad[i] ^= 0x20;
    const SignatureCheck c = Verify(verifier, "COMMAND", bad);
    EXPECT_TRUE(c == SignatureCheck::kBadSignature || c == SignatureCheck::kUnsigned) << i;
  }
  EXPECT_EQ(Verify(verifier, "COMMAND", kMessage), SignatureCheck::kUnsigned);
  Signer stranger(std::string(32, 'x'));
  EXPECT_EQ(
      Verify(verifier, "COMMAND", stranger.Sign("COMMAND", kMessage.data(), kMessage.size(), kNow)),
      SignatureCheck::kBadSignature);
  // Signed 11 s before (or after) the receiver's clock: beyond the 10 s window.
  const std::string old = signer.Sign("DG_REQUEST", kMessage.data(), kMessage.size(), kNow);
  EXPECT_EQ(Verify(verifier, "DG_REQUEST", old, kNow + 11'000'000), SignatureCheck::kStale);
  EXPECT_EQ(Verify(verifier, "DG_REQUEST", old, kNow - 11'000'000), SignatureCheck::kStale);
  EXPECT_EQ(Verify(verifier, "DG_REQUEST", old, kNow + 9'000'000), SignatureCheck::kAccepted);
  EXPECT_STREQ(ToString(SignatureCheck::kBadSignature), "bad signature");
}

TEST(SigningTest, SequencesIncreaseEvenWhenTheClockStalls) {
  Signer signer(kKey);
  Verifier verifier(kKey);
  for (int i = 0; i < 100; ++i) {  // 100 messages in the same microsecond
    const std::string m = signer.Sign("TASK_REFERENCE", kMessage.data(), kMessage.size(), kNow);
    ASSERT_EQ(Verify(verifier, "TASK_REFERENCE", m), SignatureCheck::kAccepted) << i;
  }
}

TEST(SigningTest, KeyFilesAreCheckedAndTrimmed) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / ("signing_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const auto write = [&](const std::string& name, const std::string& text, mode_t mode) {
    const std::string path = (dir / name).string();
    std::ofstream(path) << text;
    chmod(path.c_str(), mode);
    return path;
  };
  const std::string hex = "0123456789abcdef0123456789abcdef0123456789abcdef0123456789abcdef";
  EXPECT_EQ(LoadKey(write("good", hex + "\n", 0600)), hex);
  EXPECT_THROW(LoadKey(write("short", "too short\n", 0600)), std::runtime_error);
  EXPECT_THROW(LoadKey(write("open", hex, 0644)), std::runtime_error);
  EXPECT_THROW(LoadKey((dir / "missing").string()), std::runtime_error);
  try {
    LoadKey(write("open2", hex, 0640));
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("chmod 600"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace marionette::wire
