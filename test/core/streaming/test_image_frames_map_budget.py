"""The default map budget follows the limits the process really has: physical memory, cgroup v2
memory.max / v1 memory.limit_in_bytes (its own cgroup and ancestors), ulimit -v / -d; the
tightest one wins (fake /proc and /sys trees, fake rlimits)."""
import resource

from zeroshot_calib_ros.core.streaming.image_frames import default_map_budget, memory_limits

GiB = 2**30


def fake_root(tmp_path, cgroup_line='0::/\n', files=None, mem_total_kib=24 * 2**20, vm_size_kib=2**20,
              vm_data_kib=2**19):
    (tmp_path / 'proc' / 'self').mkdir(parents=True)
    (tmp_path / 'proc' / 'meminfo').write_text(f'MemTotal:       {mem_total_kib} kB\nMemFree: 1 kB\n')
    (tmp_path / 'proc' / 'self' / 'cgroup').write_text(cgroup_line)
    (tmp_path / 'proc' / 'self' / 'status').write_text(
        f'Name:\tnode\nVmPeak:\t 9 kB\nVmSize:\t {vm_size_kib} kB\nVmData:\t {vm_data_kib} kB\n')
    for rel, text in (files or {}).items():
        f = tmp_path / rel
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    return str(tmp_path)


def rlimits(as_bytes=resource.RLIM_INFINITY, data_bytes=resource.RLIM_INFINITY):
    def getrlimit(which):
        value = {resource.RLIMIT_AS: as_bytes, resource.RLIMIT_DATA: data_bytes}.get(which, resource.RLIM_INFINITY)
        return value, value
    return getrlimit


def test_no_limits_an_eighth_of_physical_memory(tmp_path):
    mb, why = default_map_budget(fake_root(tmp_path), rlimits())
    assert mb == 3 * 1024 and why == 'an eighth of physical memory'


def test_cgroup_v2_memory_max_of_the_own_group_or_an_ancestor(tmp_path):
    root = fake_root(tmp_path, '0::/a/b\n', {
        'sys/fs/cgroup/a/b/memory.max': 'max\n', 'sys/fs/cgroup/a/b/memory.current': '0\n',
        'sys/fs/cgroup/a/memory.max': f'{4 * GiB}\n', 'sys/fs/cgroup/a/memory.current': f'{GiB}\n'})
    mb, why = default_map_budget(root, rlimits())
    assert mb == 3 * 1024 // 8 and 'cgroup memory.max 4096 MiB (1024 MiB in use)' in why


def test_cgroup_v1_memory_limit_in_bytes_and_its_no_limit_value(tmp_path):
    root = fake_root(tmp_path, '4:memory:/docker/x\n3:cpu:/\n', {
        'sys/fs/cgroup/memory/docker/x/memory.limit_in_bytes': f'{2 * GiB}\n',
        'sys/fs/cgroup/memory/docker/x/memory.usage_in_bytes': '0\n',
        'sys/fs/cgroup/memory/memory.limit_in_bytes': '9223372036854771712\n'})
    mb, why = default_map_budget(root, rlimits())
    assert mb == 256 and 'cgroup memory.limit_in_bytes 2048 MiB' in why


def test_rlimit_as_counts_the_address_space_already_mapped(tmp_path):
    root = fake_root(tmp_path, vm_size_kib=2**20)  # 1 GiB mapped
    mb, why = default_map_budget(root, rlimits(as_bytes=3 * GiB))
    assert mb == 2 * 1024 // 8 and 'ulimit -v (RLIMIT_AS) 3072 MiB (1024 MiB mapped)' in why


def test_rlimit_data_and_the_smallest_limit_wins(tmp_path):
    root = fake_root(tmp_path, '0::/\n', {'sys/fs/cgroup/memory.max': f'{8 * GiB}\n'}, vm_data_kib=0)
    limits = memory_limits(root, rlimits(as_bytes=16 * GiB, data_bytes=GiB))
    assert len(limits) == 4
    mb, why = default_map_budget(root, rlimits(as_bytes=16 * GiB, data_bytes=GiB))
    assert mb == 128 and 'ulimit -d (RLIMIT_DATA) 1024 MiB' in why


def test_the_budget_never_drops_below_64_mib(tmp_path):
    mb, _ = default_map_budget(fake_root(tmp_path, vm_size_kib=2**20), rlimits(as_bytes=GiB + 2**20))
    assert mb == 64
