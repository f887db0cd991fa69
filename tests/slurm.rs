//! `volterra slurm` on a real single-node Slurm cluster (Debian's slurmctld, slurmd,
//! slurm-client and munge, which tests/setup-system.sh installs): the test starts munged,
//! slurmctld and slurmd from a minimal configuration under a temporary directory (node on
//! 127.0.0.1, free ports, no accounting, proctrack/linuxproc, task/none); a 24-step series
//! rendered serially, by 2 shards and by a job array gives the same files bit for bit; a job
//! array for the built-in plume series is checked against the serial render the same way; then kills one task mid-frame and checks that a resubmission with --resume
//! renders only what is missing and that no partial file is left; two failed tasks of an
//! array submitted again alone (`sbatch --array=1,3`) render their own frames. The daemons are stopped
//! by PID when the test ends, also when a check fails. Without Slurm the test skips
//! locally and fails under CI.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const DAEMONS: [&str; 3] = ["munged", "slurmctld", "slurmd"];
const CLIENTS: [&str; 4] = ["sbatch", "scancel", "sinfo", "squeue"];

/// Where a program is on PATH (or in the sbin folders, where Debian puts the daemons).
fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/sbin", "/usr/local/sbin"].map(PathBuf::from))
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// A port nobody listens on now.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The running cluster: its daemons (children of this test, so their PIDs are known) and
/// its configuration. Dropping it cancels every job and stops the daemons by PID.
struct Cluster {
    dir: tempfile::TempDir,
    conf: PathBuf,
    daemons: Vec<(String, Child)>,
}

impl Cluster {
    fn start() -> Cluster {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().to_path_buf();
        let d = d.as_path();
        for sub in ["state", "spool"] {
            std::fs::create_dir_all(d.join(sub)).unwrap();
        }
        // munge: a fresh key, the daemon on its own socket (as root it needs --force).
        let key: Vec<u8> = (0..1024u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8 ^ (std::process::id() as u8)).collect();
        std::fs::write(d.join("munge.key"), key).unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(d.join("munge.key"), std::fs::Permissions::from_mode(0o400)).unwrap();
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap().trim().split('.').next().unwrap().to_string();
        let (ctld_port, slurmd_port) = (free_port(), free_port());
        let p = |name: &str| d.join(name).display().to_string();
        let conf = d.join("slurm.conf");
        std::fs::write(
            &conf,
            format!(
                "ClusterName=volterra-test\nSlurmctldHost={host}(127.0.0.1)\nSlurmctldPort={ctld_port}\nSlurmdPort={slurmd_port}\n\
                 AuthType=auth/munge\nAuthInfo=socket={}\nCredType=cred/munge\nSlurmUser=root\nSlurmdUser=root\n\
                 StateSaveLocation={}\nSlurmdSpoolDir={}\nSlurmctldPidFile={}\nSlurmdPidFile={}\n\
                 SlurmctldLogFile={}\nSlurmdLogFile={}\nProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n\
                 JobAcctGatherType=jobacct_gather/none\nAccountingStorageType=accounting_storage/none\n\
                 SchedulerType=sched/backfill\nSelectType=select/cons_tres\nSelectTypeParameters=CR_Core\nMpiDefault=none\n\
                 ReturnToService=2\nKillWait=5\nNodeName={host} NodeAddr=127.0.0.1 CPUs=2 State=UNKNOWN\n\
                 PartitionName=main Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n",
                p("munge.socket"),
                p("state"),
                p("spool"),
                p("slurmctld.pid"),
                p("slurmd.pid"),
                p("slurmctld.log"),
                p("slurmd.log"),
            ),
        )
        .unwrap();
        let mut cluster = Cluster { conf: conf.clone(), daemons: vec![], dir };
        let spawn = |name: &str, args: Vec<String>| -> Child {
            let log = std::fs::File::create(d.join(format!("{name}.out"))).unwrap();
            Command::new(which(name).unwrap())
                .args(args)
                .env("SLURM_CONF", &conf)
                .stdin(Stdio::null())
                .stdout(log.try_clone().unwrap())
                .stderr(log)
                .spawn()
                .unwrap_or_else(|e| panic!("{name}: {e}"))
        };
        let munged = spawn(
            "munged",
            vec![
                "--force".into(),
                "--foreground".into(),
                format!("--socket={}", p("munge.socket")),
                format!("--key-file={}", p("munge.key")),
                format!("--pid-file={}", p("munged.pid")),
                format!("--log-file={}", p("munged.log")),
                format!("--seed-file={}", p("munge.seed")),
            ],
        );
        cluster.daemons.push(("munged".into(), munged));
        cluster.wait_for("munge's socket", Duration::from_secs(20), |c| c.dir.path().join("munge.socket").exists());
        for daemon in ["slurmctld", "slurmd"] {
            let child = spawn(daemon, vec!["-D".into(), "-f".into(), conf.display().to_string()]);
            cluster.daemons.push((daemon.into(), child));
        }
        cluster.wait_for("the node to be idle", Duration::from_secs(60), |c| {
            c.client("sinfo", &["-h", "-o", "%T"]).map(|o| String::from_utf8_lossy(&o.stdout).trim() == "idle").unwrap_or(false)
        });
        cluster
    }

    /// Runs a Slurm client against this cluster.
    fn client(&self, name: &str, args: &[&str]) -> Option<Output> {
        Command::new(which(name)?).args(args).env("SLURM_CONF", &self.conf).output().ok()
    }

    fn wait_for(&mut self, what: &str, limit: Duration, ready: impl Fn(&Cluster) -> bool) {
        let t = Instant::now();
        while !ready(self) {
            for (name, child) in &mut self.daemons {
                if let Ok(Some(status)) = child.try_wait() {
                    let log = std::fs::read_to_string(self.dir.path().join(format!("{name}.out"))).unwrap_or_default();
                    panic!("{name} exited ({status}) while waiting for {what}:\n{log}");
                }
            }
            assert!(t.elapsed() < limit, "waited {limit:?} for {what}; logs in {}", self.dir.path().display());
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    /// Waits until the job has left the queue (finished, failed or cancelled).
    fn wait_job(&mut self, id: &str) {
        self.wait_for(&format!("job {id} to end"), Duration::from_secs(300), |c| {
            c.client("squeue", &["-h", "-j", id]).map(|o| String::from_utf8_lossy(&o.stdout).trim().is_empty()).unwrap_or(true)
        });
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        // Every job first (its tasks run under slurmd's step daemons), then the daemons,
        // newest first, by PID.
        let _ = self.client("scancel", &["--full", "--user", "root"]);
        std::thread::sleep(Duration::from_millis(500));
        for (_, child) in self.daemons.iter_mut().rev() {
            let _ = Command::new("kill").arg("-TERM").arg(child.id().to_string()).status();
        }
        for (name, child) in self.daemons.iter_mut().rev() {
            let t = Instant::now();
            while matches!(child.try_wait(), Ok(None)) && t.elapsed() < Duration::from_secs(10) {
                std::thread::sleep(Duration::from_millis(100));
            }
            if matches!(child.try_wait(), Ok(None)) {
                eprintln!("{name} ({}) did not stop on SIGTERM: killed", child.id());
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

fn volterra(args: &[&str], conf: Option<&Path>) -> Output {
    let mut c = Command::new(common::volterra_bin());
    c.args(args).env("VOLTERRA_CACHE_MAX", "0").env("RAYON_NUM_THREADS", "2");
    if let Some(conf) = conf {
        c.env("SLURM_CONF", conf);
    }
    c.output().unwrap()
}

fn ok(out: &Output) -> String {
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{err}");
    err
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn exr_frames(dir: &Path) -> Vec<String> {
    listing(dir).into_iter().filter(|n| n.starts_with("f_") && n.ends_with(".exr")).collect()
}

#[test]
fn a_job_array_renders_every_frame_as_the_serial_render_and_a_resubmission_finishes_a_killed_task() {
    let missing: Vec<&str> = DAEMONS.iter().chain(&CLIENTS).filter(|n| which(n).is_none()).copied().collect();
    if !missing.is_empty() {
        let why = format!("Slurm is not installed (missing {}): run tests/setup-system.sh", missing.join(", "));
        assert!(!common::under_ci(), "{why}");
        eprintln!("skipped: {why}");
        return;
    }
    let t = Instant::now();
    let mut cluster = Cluster::start();
    eprintln!("cluster up in {:.1} s", t.elapsed().as_secs_f64());
    let conf = cluster.conf.clone();

    twenty_four_frames_serially_by_two_shards_and_by_the_array(&conf);

    // The built-in plume series, 6 steps; frames heavy enough (≈ 1 s each on one thread)
    // that a task can be killed in the middle of one.
    let work = tempfile::tempdir().unwrap();
    volterra::samples::write_plume_series(&work.path().join("series"), 6, 6000).unwrap();
    let scene = work.path().join("plume.toml");
    std::fs::write(
        &scene,
        "[image]\nwidth = 160\nheight = 160\n[camera]\nposition = [0.5, -1.6, 0.5]\nfocal_point = [0.5, 0.5, 0.45]\n\
         [orbit]\n[[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.6, -0.5]\nintensity = 3.0\n\
         [[node]]\nname = \"plume\"\nkind = \"particles\"\nfile = \"series/plume.pvd\"\nrenderer = \"smoke\"\n\
         medium = { c_ext = 10.0, albedo = 0.9, g = 0.3 }\nsettings = { photons = 20000, samples = 16 }\n",
    )
    .unwrap();
    let s = scene.to_str().unwrap();
    let dirs = ["serial", "array", "killed"].map(|n| work.path().join(n));
    for d in &dirs {
        std::fs::create_dir_all(d).unwrap();
    }
    let out = |k: usize| dirs[k].join("f.exr").display().to_string();
    ok(&volterra(&["render", s, "-o", &out(0), "--frames"], None));
    let serial = exr_frames(&dirs[0]);
    assert_eq!(serial.len(), 6);

    // The job array, waited for; every frame as the serial render's, bit for bit.
    let r = volterra(&["slurm", s, "-o", &out(1), "--frames", "--tasks", "3", "--resume", "--submit", "--wait"], Some(&conf));
    ok(&r);
    assert_eq!(exr_frames(&dirs[1]), serial);
    for f in &serial {
        assert_eq!(std::fs::read(dirs[0].join(f)).unwrap(), std::fs::read(dirs[1].join(f)).unwrap(), "{f}");
    }
    let logs: Vec<String> = listing(&dirs[1]).into_iter().filter(|n| n.ends_with(".log")).collect();
    assert_eq!(logs.len(), 3, "a log per task: {logs:?}");

    // Again without waiting; task 1 (frames 1 and 4) is cancelled once it has written its
    // first frame, so it dies in the middle of its second.
    let r = volterra(&["slurm", s, "-o", &out(2), "--frames", "--tasks", "3", "--resume", "--submit"], Some(&conf));
    ok(&r);
    let job = String::from_utf8_lossy(&r.stdout).trim().to_string();
    assert!(job.chars().all(|c| c.is_ascii_digit()) && !job.is_empty(), "job id '{job}'");
    let first = dirs[2].join("f_0001.exr");
    cluster.wait_for("task 1's first frame", Duration::from_secs(120), |_| first.exists());
    let scancel = cluster.client("scancel", &[&format!("{job}_1")]).unwrap();
    assert!(scancel.status.success(), "{}", String::from_utf8_lossy(&scancel.stderr));
    cluster.wait_job(&job);
    // It was running (rendering its second frame) when the signal came.
    let log1 = std::fs::read_to_string(dirs[2].join(format!("slurm-plume-{job}_1.log"))).unwrap();
    assert!(log1.contains("interrupted by SIGTERM"), "{log1}");
    let after_kill = exr_frames(&dirs[2]);
    assert!(!after_kill.contains(&"f_0004.exr".to_string()), "task 1 was cancelled before its last frame: {after_kill:?}");
    // No partial output: the killed task's unfinished frame left no file.
    let partial: Vec<String> = listing(&dirs[2]).into_iter().filter(|n| n.ends_with(".tmp")).collect();
    assert!(partial.is_empty(), "{partial:?}");
    let stamps: Vec<_> = after_kill.iter().map(|f| std::fs::metadata(dirs[2].join(f)).unwrap().modified().unwrap()).collect();

    // The resubmission renders only what is missing, and the whole animation is the serial one.
    let r = volterra(&["slurm", s, "-o", &out(2), "--frames", "--tasks", "3", "--resume", "--submit", "--wait"], Some(&conf));
    ok(&r);
    let job2 = String::from_utf8_lossy(&r.stdout).trim().to_string();
    assert_eq!(exr_frames(&dirs[2]), serial);
    for f in &serial {
        assert_eq!(std::fs::read(dirs[0].join(f)).unwrap(), std::fs::read(dirs[2].join(f)).unwrap(), "{f}");
    }
    let restamped: Vec<_> = after_kill.iter().map(|f| std::fs::metadata(dirs[2].join(f)).unwrap().modified().unwrap()).collect();
    assert_eq!(stamps, restamped, "frames written before the kill are not rendered again");
    let rendered: usize = listing(&dirs[2])
        .into_iter()
        .filter(|n| n.starts_with(&format!("slurm-plume-{job2}_")))
        .map(|n| {
            let log = std::fs::read_to_string(dirs[2].join(&n)).unwrap();
            let line = log.lines().find(|l| l.contains("of the animation's")).unwrap_or_else(|| panic!("{n}: {log}"));
            line.split(": ").last().unwrap().split_whitespace().next().unwrap().parse::<usize>().unwrap()
        })
        .sum();
    assert_eq!(rendered, serial.len() - after_kill.len(), "the resubmission renders exactly the missing frames");
    eprintln!("whole test {:.1} s", t.elapsed().as_secs_f64());
}

/// The proof: a 24-step series rendered serially, by 2 shards and by a Slurm job
/// array gives the same files, bit for bit (light smoke frames: seeds per frame are what
/// is tested, not the load).
fn twenty_four_frames_serially_by_two_shards_and_by_the_array(conf: &Path) {
    let work = tempfile::tempdir().unwrap();
    volterra::samples::write_plume_series(&work.path().join("series"), 24, 2000).unwrap();
    let scene = work.path().join("plume24.toml");
    std::fs::write(
        &scene,
        "[image]\nwidth = 64\nheight = 64\n[camera]\nposition = [0.5, -1.6, 0.5]\nfocal_point = [0.5, 0.5, 0.45]\n\
         [orbit]\n[[light]]\nkind = \"directional\"\ndirection = [-1.0, 0.6, -0.5]\nintensity = 3.0\n\
         [[node]]\nname = \"plume\"\nkind = \"particles\"\nfile = \"series/plume.pvd\"\nrenderer = \"smoke\"\n\
         medium = { c_ext = 10.0, albedo = 0.9, g = 0.3 }\nsettings = { photons = 3000, samples = 2 }\n",
    )
    .unwrap();
    let s = scene.to_str().unwrap();
    let dirs = ["serial", "shards", "array"].map(|n| work.path().join(n));
    for d in &dirs {
        std::fs::create_dir_all(d).unwrap();
    }
    let out = |k: usize| dirs[k].join("f.exr").display().to_string();
    ok(&volterra(&["render", s, "-o", &out(0), "--frames"], None));
    for k in 0..2 {
        ok(&volterra(&["render", s, "-o", &out(1), "--frames", "--shard", &format!("{k}/2")], None));
    }
    ok(&volterra(&["slurm", s, "-o", &out(2), "--frames", "--tasks", "4", "--submit", "--wait"], Some(conf)));
    let serial = exr_frames(&dirs[0]);
    assert_eq!(serial.len(), 24);
    for d in &dirs[1..] {
        assert_eq!(exr_frames(d), serial, "{}", d.display());
        for f in &serial {
            assert_eq!(std::fs::read(dirs[0].join(f)).unwrap(), std::fs::read(d.join(f)).unwrap(), "{} {f}", d.display());
        }
    }

    // Slurm's way to re-run failed tasks: two tasks fail (a folder stands where each one's
    // first frame goes), and only those two are submitted again (`sbatch --array=1,3`).
    // Each renders its own frames — the script names the array's size — and the whole
    // animation is the serial one, bit for bit.
    let subset = work.path().join("subset");
    std::fs::create_dir_all(&subset).unwrap();
    for f in ["f_0001.exr", "f_0003.exr"] {
        std::fs::create_dir(subset.join(f)).unwrap();
    }
    let out = subset.join("f.exr").display().to_string();
    let r = volterra(&["slurm", s, "-o", &out, "--frames", "--tasks", "4", "--submit", "--wait"], Some(conf));
    assert!(!r.status.success(), "two tasks could not write their frames: {}", String::from_utf8_lossy(&r.stderr));
    let written = exr_frames(&subset).into_iter().filter(|f| subset.join(f).is_file()).count();
    assert_eq!(written, 12, "tasks 0 and 2 rendered their frames, 1 and 3 none: {:?}", exr_frames(&subset));
    for f in ["f_0001.exr", "f_0003.exr"] {
        std::fs::remove_dir(subset.join(f)).unwrap();
    }
    let script = subset.join("volterra-plume24.sbatch");
    let again =
        Command::new(which("sbatch").unwrap()).args(["--array=1,3", "--wait"]).arg(&script).env("SLURM_CONF", conf).output().unwrap();
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert_eq!(exr_frames(&subset), serial);
    for f in &serial {
        assert_eq!(std::fs::read(dirs[0].join(f)).unwrap(), std::fs::read(subset.join(f)).unwrap(), "re-run subset: {f}");
    }
    let text = std::fs::read_to_string(&script).unwrap();
    assert!(text.contains("/4\"") && text.contains("LP_NUM_THREADS"), "{text}");
}
