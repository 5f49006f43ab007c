#!/usr/bin/env python3
"""ROS across machines, and closing ROS to an untrusted network: three hosts made of network namespaces.

The gym env across machines (test 3): cartpole_gym.launch's sims on A, robot_ai.envs' vector env on B.

Host A runs `cartpole.launch` (master, rosout, the sim, forward_kinematics, the controller); host B is a
trusted machine, host C an untrusted one; A is joined to each by a veth pair. Every packet stays inside the
namespaces this test makes. Needs root (ip netns), as CI has.

- docs/network.md's "Across machines" steps: with ROS_IP set on A and B, B echoes A's frames with tf_echo and calls
  A's services; C, which nobody set up, reaches A's master too (ROS 1 has no authentication).
- docs/network.md's firewall for that case (nftables on A: new connections only from loopback and B): B still works,
  C reaches nothing.
- Loopback mode (ROS_HOSTNAME=localhost, as make demo): from B the master and the rospy nodes refuse
  connections, but Debian's roscpp rosout answers XML-RPC (getPid; its `shutdown` would answer too). docs/network.md's
  loopback firewall (no new connection from any other interface) closes it, and the graph on A still works.
"""
import ast
import os
import shutil
import subprocess
import sys
import textwrap
import time
import unittest

import rostest


def system_tool(name):
    """The absolute path of an administrator's tool: Debian puts nft (and ip's other name) in /usr/sbin, which a
    plain user's PATH (/usr/local/bin:/usr/bin:/bin) does not hold."""
    found = shutil.which(name, path=os.pathsep.join([os.environ.get('PATH', ''), '/usr/sbin', '/sbin']))
    if found is None:
        raise RuntimeError(f'{name} is not installed (Debian: apt-get install {PACKAGES[name]})')
    return found


HERE = os.path.dirname(os.path.realpath(__file__))
PACKAGES = {'ip': 'iproute2', 'nft': 'nftables'}
IP, NFT = system_tool('ip'), system_tool('nft')

TAG = f'{os.getpid() % 100000}'
A, B, C = f'rai{TAG}a', f'rai{TAG}b', f'rai{TAG}c'
A_TO_B, B_ADDR = '10.231.0.1', '10.231.0.2'
A_TO_C, C_ADDR = '10.232.0.1', '10.232.0.2'

XMLRPC_CALL = textwrap.dedent('''
    import sys, xmlrpc.client
    try:
        print(xmlrpc.client.ServerProxy(sys.argv[1]).__getattr__(sys.argv[2])('/probe', *sys.argv[3:]))
    except Exception as e:
        print('refused', type(e).__name__, e)
''')


def sh(*args, check=True, timeout=30, **kw):
    return subprocess.run(list(args), check=check, capture_output=True, text=True, timeout=timeout, **kw)


def in_ns(ns, env, *args, timeout=30):
    """Run args inside namespace ns with env (the ROS variables of that host); (status, output)."""
    proc = subprocess.run([IP, 'netns', 'exec', ns] + host_env(env) + list(args),
                          capture_output=True, text=True, timeout=timeout)
    return proc.returncode, proc.stdout + proc.stderr


def host_env(env):
    """`env` arguments that give a host exactly these ROS variables (the test's own ROS_HOSTNAME is not A's)."""
    return ['env', '-u', 'ROS_HOSTNAME', '-u', 'ROS_IP', '-u', 'ROS_MASTER_URI'] + [f'{k}={v}' for k, v in env.items()]


def xmlrpc(ns, url, method, *args, timeout=10):
    """The answer of an XML-RPC call from namespace ns (ROS's getPid, getSystemState, ...), or 'refused ...'."""
    _, out = in_ns(ns, {}, 'timeout', str(timeout), 'python3', '-c', XMLRPC_CALL, url, method, *args,
                   timeout=timeout + 10)
    return out.strip() or 'refused: no answer within the timeout'


def nft(ns, rules):
    proc = subprocess.run([IP, 'netns', 'exec', ns, NFT, '-f', '-'], input=rules, capture_output=True,
                          text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr


# docs/network.md's rules, word for word ("A network you do not trust"); across machines, the other ROS
# machines are admitted before the last line.
LOOPBACK_ONLY_RULES = '''
table inet ros_guard {
  chain input {
    type filter hook input priority 0; policy accept;
    iifname "lo" accept
    ct state established,related accept
    tcp flags syn drop
  }
}
'''
TRUSTED_PEERS_RULES = LOOPBACK_ONLY_RULES.replace('    tcp flags syn drop',
                                                  '    ip saddr { TRUSTED } accept\n    tcp flags syn drop')


class Hosts:
    """Namespaces A, B, C; A joined to B and to C by veth pairs."""

    def __init__(self):
        for ns in (A, B, C):
            sh(IP, 'netns', 'add', ns)
            sh(IP, 'netns', 'exec', ns, IP, 'link', 'set', 'lo', 'up')
        for other, here, there in ((B, A_TO_B, B_ADDR), (C, A_TO_C, C_ADDR)):
            a_end, o_end = f'{A}{other[-1]}', f'{other}a'
            sh(IP, 'link', 'add', a_end, 'netns', A, 'type', 'veth', 'peer', 'name', o_end, 'netns', other)
            for ns, dev, addr in ((A, a_end, here), (other, o_end, there)):
                sh(IP, 'netns', 'exec', ns, IP, 'addr', 'add', f'{addr}/24', 'dev', dev)
                sh(IP, 'netns', 'exec', ns, IP, 'link', 'set', dev, 'up')

    def close(self):
        for ns in (A, B, C):
            pids = sh(IP, 'netns', 'pids', ns, check=False).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), 9)
                except (ProcessLookupError, ValueError):
                    pass
            sh(IP, 'netns', 'del', ns, check=False)


class Launch:
    """cartpole.launch on host A with the given ROS variables, in a session of its own."""

    def __init__(self, env):
        self.env = env
        self.proc = subprocess.Popen([IP, 'netns', 'exec', A] + host_env(env) +
                                     ['roslaunch', 'robot_ai', 'cartpole.launch'], stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.time() + 90
        while time.time() < deadline:
            status, out = in_ns(A, env, 'rosservice', 'list')
            if status == 0 and '/cartpole_sim/push' in out:
                return
            time.sleep(1.0)
        raise AssertionError(f'cartpole.launch on host A did not come up: {out}')

    def uri_of(self, node):
        """A node's XML-RPC URI, asked of the master on A."""
        answer = xmlrpc(A, self.env['ROS_MASTER_URI'], 'lookupNode', node)
        code, _, uri = ast.literal_eval(answer)
        assert code == 1, answer
        return uri

    def close(self):
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 2)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait()


class TestAcrossMachines(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        if os.geteuid() != 0:
            raise AssertionError('this test makes network namespaces: run it as root (CI does)')
        cls.hosts = Hosts()

    @classmethod
    def tearDownClass(cls):
        cls.hosts.close()

    def tearDown(self):
        sh(IP, 'netns', 'exec', A, NFT, 'flush', 'ruleset', check=False)

    def test_1_across_machines_as_the_readme_says_and_its_firewall(self):
        master = f'http://{A_TO_B}:11311'
        launch = Launch({'ROS_IP': A_TO_B, 'ROS_MASTER_URI': master})
        try:
            b = {'ROS_IP': B_ADDR, 'ROS_MASTER_URI': master}
            self.assert_b_uses_a(b)
            # C was never set up: ROS 1 lets it read the whole graph (and could stop any node)
            state = xmlrpc(C, f'http://{A_TO_C}:11311', 'getSystemState')
            self.assertIn('/cartpole_sim/push', state)
            nft(A, TRUSTED_PEERS_RULES.replace('TRUSTED', B_ADDR))
            self.assertIn('refused', xmlrpc(C, f'http://{A_TO_C}:11311', 'getSystemState', timeout=5))
            sim = launch.uri_of('/cartpole_sim').replace(A_TO_B, A_TO_C)
            self.assertIn('refused', xmlrpc(C, sim, 'getPid', timeout=5))
            self.assert_b_uses_a(b)
        finally:
            launch.close()

    def assert_b_uses_a(self, b):
        status, out = in_ns(B, b, 'timeout', '-s', 'INT', '15', 'rosrun', 'tf', 'tf_echo', 'rail', 'pole', timeout=40)
        self.assertIn('- Translation:', out)
        self.assertIn('- Rotation: in Quaternion', out)
        status, out = in_ns(B, b, 'rosservice', 'call', '/cartpole_sim/push', 'angular_velocity: 0.01')
        self.assertEqual(status, 0, out)
        self.assertIn('success: True', out)

    def test_2_loopback_mode_rosout_answers_other_hosts_until_the_firewall(self):
        env = {'ROS_HOSTNAME': 'localhost', 'ROS_MASTER_URI': 'http://localhost:11311'}
        launch = Launch(env)
        try:
            rosout = launch.uri_of('/rosout')        # http://localhost:<port>/
            sim = launch.uri_of('/cartpole_sim')
            other_host = lambda uri: uri.replace('localhost', A_TO_B)  # noqa: E731
            self.assertIn('refused ConnectionRefusedError', xmlrpc(B, f'http://{A_TO_B}:11311', 'getSystemState'))
            self.assertIn('refused ConnectionRefusedError', xmlrpc(B, other_host(sim), 'getPid'))
            # the README says so: Debian's roscpp rosout listens on every interface and answers anyone
            self.assertRegex(xmlrpc(B, other_host(rosout), 'getPid'), r'^\[1, .*, \d+\]$')
            nft(A, LOOPBACK_ONLY_RULES)
            self.assertIn('refused', xmlrpc(B, other_host(rosout), 'getPid', timeout=5))
            # on A, ROS still works
            status, out = in_ns(A, env, 'rosservice', 'call', '/cartpole_sim/push', 'angular_velocity: 0.01')
            self.assertIn('success: True', out)
            self.assertRegex(xmlrpc(A, rosout, 'getPid'), r'^\[1, .*, \d+\]$')
        finally:
            launch.close()

    def test_3_the_gym_vector_env_on_one_host_with_its_sims_on_another(self):
        """robot_ai.envs across machines: the sims of cartpole_gym.launch on A, the vector env on B (and then on A
        itself); the same numbers on both hosts, and gymnasium's."""
        master = f'http://{A_TO_B}:11311'
        a_env = {'ROS_IP': A_TO_B, 'ROS_MASTER_URI': master}
        proc = subprocess.Popen([IP, 'netns', 'exec', A] + host_env(a_env) +
                                ['roslaunch', 'robot_ai', 'cartpole_gym.launch', 'sims:=3'], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, start_new_session=True)
        try:
            deadline = time.time() + 90
            out = ''
            while time.time() < deadline and '/cartpole_2/cartpole_sim/set_state' not in out:
                time.sleep(1.0)
                _, out = in_ns(A, a_env, 'rosservice', 'list')
            self.assertIn('/cartpole_2/cartpole_sim/set_state', out)
            digest = [sys.executable, os.path.join(HERE, 'ros_env_digest.py'), '3', '600', '11']
            status_b, out_b = in_ns(B, {'ROS_IP': B_ADDR, 'ROS_MASTER_URI': master}, *digest, timeout=240)
            self.assertEqual(status_b, 0, out_b)
            status_a, out_a = in_ns(A, a_env, *digest, timeout=240)
            self.assertEqual(status_a, 0, out_a)
            self.assertIn('same as gymnasium: True', out_b)
            lines = lambda text: [line for line in text.splitlines() if line.startswith(('same', 'digest'))]  # noqa
            self.assertEqual(lines(out_b), lines(out_a))
            self.assertEqual(len(lines(out_b)), 2, out_b)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, 2)
                try:
                    proc.wait(20)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, 9)
                    proc.wait()


if __name__ == '__main__':
    rostest.rosrun('robot_ai', 'test_across_machines', TestAcrossMachines)
