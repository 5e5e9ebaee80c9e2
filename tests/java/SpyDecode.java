// Decodes every message on an LCM URL the way lcm-spy does (lcm.spy.LCMTypeDatabase looks the
// fingerprint up among the classes on the classpath), and prints one line per message:
//   CHANNEL <TAB> class name <TAB> utime
// Used by tests/python/lcm/test_lcm_spy.py to prove lcm-spy decodes the project's channels.
import java.io.DataInputStream;
import java.io.IOException;
import java.lang.reflect.Constructor;
import java.nio.ByteBuffer;

import lcm.lcm.LCM;
import lcm.lcm.LCMDataInputStream;
import lcm.lcm.LCMSubscriber;
import lcm.spy.LCMTypeDatabase;

public class SpyDecode implements LCMSubscriber {
  private final LCMTypeDatabase types = new LCMTypeDatabase();

  public void messageReceived(LCM lcm, String channel, LCMDataInputStream ins) {
    try {
      byte[] data = new byte[ins.available()];
      ins.readFully(data);
      long fingerprint = ByteBuffer.wrap(data, 0, 8).getLong();
      Class<?> cls = types.getClassByFingerprint(fingerprint);
      if (cls == null) {
        System.out.println(channel + "\tUNKNOWN\t-");
        return;
      }
      Constructor<?> ctor = cls.getConstructor(byte[].class);
      Object msg = ctor.newInstance((Object) data);
      long utime = cls.getField("utime").getLong(msg);
      System.out.println(channel + "\t" + cls.getName() + "\t" + utime);
    } catch (Exception ex) {
      System.out.println(channel + "\tERROR\t" + ex);
    }
    System.out.flush();
  }

  public static void main(String[] args) throws IOException, InterruptedException {
    LCM lcm = new LCM(args[0]);
    lcm.subscribe(".*", new SpyDecode());
    System.out.println("READY");
    System.out.flush();
    Thread.sleep(Long.parseLong(args[1]));
    System.exit(0);
  }
}
