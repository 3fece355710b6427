//! The contract in three languages: the Python `ctypes` module (`python/motion_shm.py`) and the
//! C header (`include/motion_shm.h`) must lay out every payload exactly as the Rust compiler
//! does (`shm_api::layout_dump`), carry the same constants and the same iceoryx2 type names.
//! The last test runs the Python example against a minimal Rust publisher over iceoryx2.
//!
//! Needs `python3` and `cc`; the example test also needs the iceoryx2 Python package
//! (`pip install iceoryx2==0.10.0`, as `.ci/run` does). Without it the test says it skipped,
//! unless `MOTION_REQUIRE_ALL=1` (set by `.ci/run`) makes it fail.

use shm_api::contract::{
    self, AxisState, BusStats, CommandReply, CommandRequest, GroupState, MachineState,
};
use shm_api::layout_dump::{constants, layout_json, layouts};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

// ---- a small JSON reader: the documents are ours, but a parse error must say where ----------

#[derive(Debug, Clone, PartialEq)]
enum Json {
    Null,
    Bool(bool),
    Num(i64),
    Str(String),
    Arr(Vec<Json>),
    Obj(Vec<(String, Json)>),
}

impl Json {
    fn get(&self, key: &str) -> Option<&Json> {
        match self {
            Json::Obj(kv) => kv.iter().find(|(k, _)| k == key).map(|(_, v)| v),
            _ => None,
        }
    }
    fn num(&self, key: &str) -> Option<i64> {
        match self.get(key) {
            Some(Json::Num(n)) => Some(*n),
            _ => None,
        }
    }
    fn str(&self, key: &str) -> Option<&str> {
        match self.get(key) {
            Some(Json::Str(s)) => Some(s),
            _ => None,
        }
    }
    fn arr(&self, key: &str) -> &[Json] {
        match self.get(key) {
            Some(Json::Arr(a)) => a,
            _ => &[],
        }
    }
}

struct Parser<'a> {
    s: &'a [u8],
    i: usize,
}

impl Parser<'_> {
    fn parse(text: &str) -> Result<Json, String> {
        let mut p = Parser {
            s: text.as_bytes(),
            i: 0,
        };
        let v = p.value()?;
        p.ws();
        if p.i != p.s.len() {
            return Err(format!("trailing data at byte {}", p.i));
        }
        Ok(v)
    }
    fn ws(&mut self) {
        while self.s.get(self.i).is_some_and(|c| c.is_ascii_whitespace()) {
            self.i += 1;
        }
    }
    fn eat(&mut self, c: u8) -> Result<(), String> {
        self.ws();
        if self.s.get(self.i) == Some(&c) {
            self.i += 1;
            Ok(())
        } else {
            Err(format!("expected `{}` at byte {}", c as char, self.i))
        }
    }
    fn lit(&mut self, word: &str, v: Json) -> Result<Json, String> {
        if self.s[self.i..].starts_with(word.as_bytes()) {
            self.i += word.len();
            Ok(v)
        } else {
            Err(format!("bad literal at byte {}", self.i))
        }
    }
    fn value(&mut self) -> Result<Json, String> {
        self.ws();
        match self.s.get(self.i) {
            Some(b'{') => {
                self.i += 1;
                let mut kv = Vec::new();
                self.ws();
                if self.s.get(self.i) == Some(&b'}') {
                    self.i += 1;
                    return Ok(Json::Obj(kv));
                }
                loop {
                    self.ws();
                    let k = self.string()?;
                    self.eat(b':')?;
                    kv.push((k, self.value()?));
                    self.ws();
                    match self.s.get(self.i) {
                        Some(b',') => self.i += 1,
                        Some(b'}') => {
                            self.i += 1;
                            return Ok(Json::Obj(kv));
                        }
                        _ => return Err(format!("expected `,` or `}}` at byte {}", self.i)),
                    }
                }
            }
            Some(b'[') => {
                self.i += 1;
                let mut a = Vec::new();
                self.ws();
                if self.s.get(self.i) == Some(&b']') {
                    self.i += 1;
                    return Ok(Json::Arr(a));
                }
                loop {
                    a.push(self.value()?);
                    self.ws();
                    match self.s.get(self.i) {
                        Some(b',') => self.i += 1,
                        Some(b']') => {
                            self.i += 1;
                            return Ok(Json::Arr(a));
                        }
                        _ => return Err(format!("expected `,` or `]` at byte {}", self.i)),
                    }
                }
            }
            Some(b'"') => Ok(Json::Str(self.string()?)),
            Some(b'n') => self.lit("null", Json::Null),
            Some(b't') => self.lit("true", Json::Bool(true)),
            Some(b'f') => self.lit("false", Json::Bool(false)),
            Some(c) if *c == b'-' || c.is_ascii_digit() => {
                let start = self.i;
                self.i += 1;
                while self.s.get(self.i).is_some_and(|c| c.is_ascii_digit()) {
                    self.i += 1;
                }
                let text =
                    std::str::from_utf8(&self.s[start..self.i]).map_err(|e| e.to_string())?;
                text.parse()
                    .map(Json::Num)
                    .map_err(|e| format!("number `{text}` at byte {start}: {e}"))
            }
            _ => Err(format!("unexpected input at byte {}", self.i)),
        }
    }
    fn string(&mut self) -> Result<String, String> {
        self.eat(b'"')?;
        let mut out = String::new();
        loop {
            let c = *self.s.get(self.i).ok_or("unterminated string")?;
            self.i += 1;
            match c {
                b'"' => return Ok(out),
                b'\\' => {
                    let e = *self.s.get(self.i).ok_or("unterminated escape")?;
                    self.i += 1;
                    match e {
                        b'u' => {
                            let hex = self.s.get(self.i..self.i + 4).ok_or("short \\u")?;
                            let hex = std::str::from_utf8(hex).map_err(|e| e.to_string())?;
                            let code = u32::from_str_radix(hex, 16).map_err(|e| e.to_string())?;
                            out.push(char::from_u32(code).unwrap_or('\u{fffd}'));
                            self.i += 4;
                        }
                        b'n' => out.push('\n'),
                        b't' => out.push('\t'),
                        other => out.push(other as char),
                    }
                }
                _ => {
                    // Re-decode multi-byte UTF-8 from the source slice.
                    let start = self.i - 1;
                    let mut end = self.i;
                    while self.s.get(end).is_some_and(|b| b & 0xC0 == 0x80) {
                        end += 1;
                    }
                    out.push_str(
                        std::str::from_utf8(&self.s[start..end]).map_err(|e| e.to_string())?,
                    );
                    self.i = end;
                }
            }
        }
    }
}

// ---- the comparison ---------------------------------------------------------------------------

/// Every difference between the Rust layout and another language's, one sentence each.
fn differences(rust: &Json, other: &Json, lang: &str) -> Vec<String> {
    let mut out = Vec::new();
    let theirs = other.arr("types");
    for rt in rust.arr("types") {
        let name = rt.str("name").unwrap_or("?");
        let Some(ot) = theirs.iter().find(|t| t.str("name") == Some(name)) else {
            out.push(format!("{lang} lacks the type {name}"));
            continue;
        };
        for key in ["size", "align"] {
            if rt.num(key) != ot.num(key) {
                out.push(format!(
                    "{name}: {key} is {:?} in Rust, {:?} in {lang}",
                    rt.num(key),
                    ot.num(key)
                ));
            }
        }
        if rt.get("type_name") != ot.get("type_name") {
            out.push(format!(
                "{name}: iceoryx2 type name is {:?} in Rust, {:?} in {lang}",
                rt.get("type_name"),
                ot.get("type_name")
            ));
        }
        let ofields = ot.arr("fields");
        for rf in rt.arr("fields") {
            let fname = rf.str("name").unwrap_or("?");
            let Some(of) = ofields.iter().find(|f| f.str("name") == Some(fname)) else {
                out.push(format!("{lang} lacks the field {name}.{fname}"));
                continue;
            };
            for key in ["offset", "size"] {
                if rf.num(key) != of.num(key) {
                    out.push(format!(
                        "{name}.{fname}: {key} is {:?} in Rust, {:?} in {lang}",
                        rf.num(key),
                        of.num(key)
                    ));
                }
            }
        }
        for of in ofields {
            let fname = of.str("name").unwrap_or("?");
            if !rt
                .arr("fields")
                .iter()
                .any(|f| f.str("name") == Some(fname))
            {
                out.push(format!("{lang} has a field {name}.{fname} that Rust lacks"));
            }
        }
    }
    for ot in theirs {
        let name = ot.str("name").unwrap_or("?");
        if !rust
            .arr("types")
            .iter()
            .any(|t| t.str("name") == Some(name))
        {
            out.push(format!("{lang} has a type {name} that Rust lacks"));
        }
    }
    let (Some(Json::Obj(rc)), Some(Json::Obj(oc))) =
        (rust.get("constants"), other.get("constants"))
    else {
        out.push(format!("{lang}: no constants object"));
        return out;
    };
    for (k, v) in rc {
        match oc.iter().find(|(ok, _)| ok == k) {
            None => out.push(format!("{lang} lacks the constant {k}")),
            Some((_, ov)) if ov != v => {
                out.push(format!("constant {k} is {v:?} in Rust, {ov:?} in {lang}"))
            }
            Some(_) => {}
        }
    }
    for (k, _) in oc {
        if !rc.iter().any(|(rk, _)| rk == k) {
            out.push(format!("{lang} has a constant {k} that Rust lacks"));
        }
    }
    out
}

fn rust_layout() -> Json {
    Parser::parse(&layout_json()).unwrap_or_else(|e| panic!("layout_json() is not JSON: {e}"))
}

fn assert_same(other_text: &str, lang: &str) {
    let other = Parser::parse(other_text)
        .unwrap_or_else(|e| panic!("{lang} printed no valid JSON ({e}):\n{other_text}"));
    let diffs = differences(&rust_layout(), &other, lang);
    assert!(
        diffs.is_empty(),
        "{lang} disagrees with the Rust contract:\n  {}",
        diffs.join("\n  ")
    );
}

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh scratch directory for this test and process.
fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("creating the scratch directory");
    dir
}

fn run(cmd: &mut Command, what: &str) -> Output {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {what}: {e}"));
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{}{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

// ---- the comparison itself is checked, so a broken comparer cannot pass everything ----------

#[test]
fn comparison_names_the_field_that_differs() {
    let rust = rust_layout();
    assert!(differences(&rust, &rust, "Rust").is_empty());
    let text = layout_json().replace(
        "{\"name\": \"fault_code\", \"offset\": 68,",
        "{\"name\": \"fault_code\", \"offset\": 70,",
    );
    assert_ne!(text, layout_json(), "AxisState.fault_code sits at 68");
    let diffs = differences(&rust, &Parser::parse(&text).expect("json"), "X");
    assert_eq!(
        diffs,
        ["AxisState.fault_code: offset is Some(68) in Rust, Some(70) in X"]
    );
    let text = layout_json().replace("\"status.BUSY\": 6", "\"status.BUZY\": 6");
    let diffs = differences(&rust, &Parser::parse(&text).expect("json"), "X");
    assert_eq!(
        diffs,
        [
            "X lacks the constant status.BUSY",
            "X has a constant status.BUZY that Rust lacks"
        ]
    );
}

// ---- Python ---------------------------------------------------------------------------------

#[test]
fn python_ctypes_module_matches_the_rust_layout() {
    let out = run(
        Command::new("python3")
            .args(["-c", "import motion_shm; print(motion_shm.layout_json())"])
            .env("PYTHONPATH", crate_dir().join("python"))
            .env("PYTHONDONTWRITEBYTECODE", "1"),
        "python3 (motion_shm.layout_json)",
    );
    assert_same(&String::from_utf8_lossy(&out.stdout), "Python");
}

// ---- C --------------------------------------------------------------------------------------

/// `AxisState` -> `AXIS_STATE`.
fn upper_snake(camel: &str) -> String {
    let mut out = String::new();
    for (i, c) in camel.chars().enumerate() {
        if c.is_ascii_uppercase() && i > 0 {
            out.push('_');
        }
        out.push(c.to_ascii_uppercase());
    }
    out
}

/// A C program printing the header's layout as JSON, generated from the Rust list of types,
/// fields and constants: a name the header lacks fails the compile with that name.
fn c_dump_program() -> String {
    let mut c = String::from(
        "#include <stdio.h>\n#include \"motion_shm.h\"\n\n\
         static void str(const char *s) {\n  putchar('\"');\n  for (; *s; s++) {\n    \
         if (*s == '\"' || *s == '\\\\') putchar('\\\\');\n    putchar(*s);\n  }\n  \
         putchar('\"');\n}\n\n\
         #define FIELD(T, f, sep) printf(\"%s{\\\"name\\\": \\\"%s\\\", \\\"offset\\\": %zu, \
         \\\"size\\\": %zu}\", sep, #f, offsetof(T, f), sizeof(((T *)0)->f))\n\n\
         int main(void) {\n  printf(\"{\\\"types\\\": [\");\n",
    );
    for (i, t) in layouts().iter().enumerate() {
        let ct = format!("Motion{}", t.name);
        c += &format!(
            "  printf(\"%s{{\\\"name\\\": \\\"{}\\\", \\\"type_name\\\": \", \"{}\");\n",
            t.name,
            if i == 0 { "" } else { "," }
        );
        if t.type_name.is_some() {
            c += &format!("  str(MOTION_{}_TYPE_NAME);\n", upper_snake(t.name));
        } else {
            c += "  printf(\"null\");\n";
        }
        c += &format!(
            "  printf(\", \\\"size\\\": %zu, \\\"align\\\": %zu, \\\"fields\\\": [\", \
             sizeof({ct}), (size_t)_Alignof({ct}));\n"
        );
        for (j, f) in t.fields.iter().enumerate() {
            c += &format!(
                "  FIELD({ct}, {}, \"{}\");\n",
                f.name,
                if j == 0 { "" } else { "," }
            );
        }
        c += "  printf(\"]}\");\n";
    }
    c += "  printf(\"], \\\"constants\\\": {\");\n";
    for (i, (name, _)) in constants().iter().enumerate() {
        let macro_name = format!("MOTION_{}", name.replace('.', "_").to_ascii_uppercase());
        c += &format!(
            "  printf(\"%s\\\"{name}\\\": %lld\", \"{}\", (long long)({macro_name}));\n",
            if i == 0 { "" } else { "," }
        );
    }
    c += "  printf(\"}}\\n\");\n  return 0;\n}\n";
    c
}

#[test]
fn c_header_matches_the_rust_layout() {
    let dir = scratch("layout_languages_c");
    let src = dir.join("dump.c");
    let exe = dir.join("dump");
    std::fs::write(&src, c_dump_program()).expect("writing dump.c");
    run(
        Command::new("cc")
            .args(["-std=c11", "-Wall", "-Wextra", "-pedantic", "-Werror", "-I"])
            .arg(crate_dir().join("include"))
            .arg(&src)
            .arg("-o")
            .arg(&exe),
        "cc (compiling the generated check against include/motion_shm.h; a missing name is \
         named by the compiler)",
    );
    let out = run(&mut Command::new(&exe), "the compiled C layout check");
    assert_same(&String::from_utf8_lossy(&out.stdout), "C");

    // The header also serves C++ clients (static_assert/alignof there); check it compiles
    // where a C++ compiler is installed.
    if Command::new("c++")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
    {
        let cpp = dir.join("include.cpp");
        std::fs::write(
            &cpp,
            "#include \"motion_shm.h\"\nint main() { return 0; }\n",
        )
        .expect("writing include.cpp");
        run(
            Command::new("c++")
                .args(["-std=c++11", "-Wall", "-Werror", "-fsyntax-only", "-I"])
                .arg(crate_dir().join("include"))
                .arg(&cpp),
            "c++ (including motion_shm.h)",
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

// ---- the Python example against a Rust publisher over iceoryx2 -----------------------------

fn python_iceoryx2_available() -> bool {
    Command::new("python3")
        .args(["-c", "import iceoryx2"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn name_field<const N: usize>(s: &str) -> [u8; N] {
    let mut out = [0u8; N];
    out[..s.len()].copy_from_slice(s.as_bytes());
    out
}

fn axis(name: &str, position: i64, state: u8, mode: u8, flags: u16) -> AxisState {
    AxisState {
        position,
        setpoint: position,
        velocity: 0,
        position_inc: position / 10,
        setpoint_inc: position / 10,
        fault_value: 0,
        fault_limit: 0,
        force_permille: 0,
        status_bits: 0,
        flags,
        state,
        mode,
        fault: contract::fault::NONE,
        activity: 0,
        fault_code: 0,
        active_record: -1,
        name: name_field(name),
        unit: name_field("mm"),
        reserved1: [0; 32],
    }
}

/// A machine with two axes: `lift` (ready, homed) and `slide` (disabled).
fn two_axis_state() -> MachineState {
    use contract::{axis_flags as fl, axis_mode, axis_state};
    let empty_axis = axis("", 0, axis_state::OFFLINE, axis_mode::OFF, 0);
    let empty_group = GroupState {
        active_record: -1,
        record: -1,
        reached: -1,
        override_percent: 100,
        chain_state: 0,
        rc1: 0,
        rcc: 0,
        motion: 0,
        axis_count: 0,
        activity: 0,
        reserved0: [0; 2],
        axes: [0; contract::MAX_GROUP_AXES],
        name: [0; contract::NAME_LEN],
        reserved1: [0; 8],
    };
    let mut s = MachineState {
        version: contract::LAYOUT_VERSION,
        layout_hash: contract::LAYOUT_HASH,
        cycle: 0,
        sync_time_ns: 0,
        publish_time_ns: 0,
        cycle_ns: 4_000_000,
        axis_count: 2,
        group_count: 0,
        inputs: 0,
        virtual_time: 0,
        reserved0: [0; 3],
        bus: BusStats {
            frames_sent: 0,
            frames_received: 0,
            tx_refused: 0,
            rx_dropped: 0,
            skipped_cycles: 0,
            step_ns: 0,
            wake_late_us: 0,
        },
        axes: [empty_axis; contract::MAX_AXES],
        groups: [empty_group; contract::MAX_GROUPS],
    };
    s.axes[0] = axis(
        "lift",
        1_500_000,
        axis_state::READY,
        axis_mode::ON,
        fl::ONLINE | fl::ENABLED | fl::HOMED,
    );
    s.axes[1] = axis(
        "slide",
        -250_000,
        axis_state::DISABLED,
        axis_mode::OFF,
        fl::ONLINE,
    );
    s
}

/// The answer the test coordinator gives to a request in `cycle`.
fn reply_to(req: &CommandRequest, cycle: u64) -> CommandReply {
    let mut reply = CommandReply {
        tag: req.tag,
        cycle: cycle + 2,
        value: 0,
        min: 0,
        max: 0,
        status: contract::status::LATCHED,
        reserved0: [0; 6],
        reason: [0; 48],
    };
    if usize::from(req.axis) >= 2 {
        reply.status = contract::status::UNKNOWN_AXIS;
        reply.value = i64::from(req.axis);
    }
    reply
}

struct ExampleRun {
    output: Output,
    requests: Vec<CommandRequest>,
    replies: Vec<CommandReply>,
    pid: u32,
}

/// Serves `prefix/state` and `prefix/command` like the coordinator (a state every 5 ms,
/// one reply per request) while `python3 script` runs; returns what it printed and received.
fn serve_while_running(prefix: &str, python_args: &[&str]) -> ExampleRun {
    use iceoryx2::prelude::*;
    set_log_level_from_env_or(LogLevel::Error);
    let node = NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .expect("iceoryx2 node");
    let _ = node.try_cleanup_dead_nodes();
    let state_name: ServiceName = format!("{prefix}/state")
        .as_str()
        .try_into()
        .expect("service name");
    let command_name: ServiceName = format!("{prefix}/command")
        .as_str()
        .try_into()
        .expect("service name");
    let state_service = node
        .service_builder(&state_name)
        .publish_subscribe::<MachineState>()
        .history_size(1)
        .max_subscribers(16)
        .enable_safe_overflow(true)
        .create()
        .expect("creating the state service");
    let publisher = state_service
        .publisher_builder()
        .create()
        .expect("state publisher");
    let command_service = node
        .service_builder(&command_name)
        .request_response::<CommandRequest, CommandReply>()
        .create()
        .expect("creating the command service");
    let server = command_service
        .server_builder()
        .create()
        .expect("command server");

    let mut child = Command::new("python3")
        .args(python_args)
        .env("PYTHONPATH", crate_dir().join("python"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting python3");
    let pid = child.id();
    let mut state = Box::new(two_axis_state());
    let mut requests = Vec::new();
    let mut replies = Vec::new();
    let give_up = Instant::now() + Duration::from_secs(30);
    loop {
        state.cycle += 1;
        let sample = publisher.loan_uninit().expect("loaning a state sample");
        sample
            .write_payload(*state)
            .send()
            .expect("publishing the state");
        while let Some(active) = server.receive().expect("receiving a command") {
            let req = *active.payload();
            let reply = reply_to(&req, state.cycle);
            active.send_copy(reply).expect("replying");
            requests.push(req);
            replies.push(reply);
        }
        if child.try_wait().expect("polling python3").is_some() {
            break;
        }
        if Instant::now() > give_up {
            let _ = child.kill();
            let out = child.wait_with_output().expect("collecting python3");
            panic!(
                "the example did not finish within 30 s:\n{}{}",
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let output = child.wait_with_output().expect("collecting python3");
    ExampleRun {
        output,
        requests,
        replies,
        pid,
    }
}

fn example_path() -> String {
    crate_dir()
        .join("python")
        .join("example_watch_and_command.py")
        .display()
        .to_string()
}

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn python_example_reads_the_state_and_commands_a_rust_coordinator() {
    if !python_iceoryx2_available() {
        // CI (.ci/run) installs the package and makes this test mandatory.
        assert!(
            std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
            "the iceoryx2 Python package is not importable and MOTION_REQUIRE_ALL=1"
        );
        {
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "SKIPPED python_example_reads_the_state_and_commands_a_rust_coordinator: the iceoryx2 \
             Python package is not installed (`pip install iceoryx2==0.10.0`, as .ci/run does)"
            );
        }
        return;
    }
    let example = example_path();
    let timeout = ["--timeout", "10"];

    // Accepted: the state is printed axis by axis, the request arrives as built, the reply
    // is printed with the cycle the coordinator latched it for.
    let prefix = format!("layout-languages-ok-{}", std::process::id());
    let mut args = vec![example.as_str(), "--prefix", &prefix, "--axis", "1"];
    args.extend(timeout);
    let run = serve_while_running(&prefix, &args);
    let (stdout, stderr) = text(&run.output);
    assert!(
        run.output.status.success(),
        "{}:\n{stdout}{stderr}",
        run.output.status
    );
    assert!(
        stdout.contains(&format!("connected to '{prefix}' (layout v1")),
        "{stdout}"
    );
    assert!(stdout.contains(": 2 axes, 0 groups"), "{stdout}");
    assert!(
        stdout.contains("axis 0 lift: READY mode ON at 1.500000 mm (setpoint 1.500000) flags ONLINE|ENABLED|HOMED fault NONE"),
        "{stdout}"
    );
    assert!(
        stdout.contains("axis 1 slide: DISABLED mode OFF at -0.250000 mm"),
        "{stdout}"
    );
    assert!(
        !stdout.contains("axis 2 "),
        "only axis_count axes: {stdout}"
    );
    assert_eq!(
        run.requests.len(),
        1,
        "exactly one command: {:?}",
        run.requests
    );
    let req = run.requests[0];
    assert_eq!(req.kind, contract::command_kind::ENABLE);
    assert_eq!(req.target, contract::target::AXIS);
    assert_eq!(req.axis, 1);
    assert_eq!(req.tag, u64::from(run.pid), "the example tags with its pid");
    assert!(
        stdout.contains(&format!(
            "command ENABLE axis 1 (tag {}): latched at cycle {}",
            run.pid, run.replies[0].cycle
        )),
        "{stdout}"
    );

    // Refused: the reply's reason is printed and the exit status says so.
    let prefix = format!("layout-languages-refused-{}", std::process::id());
    let mut args = vec![example.as_str(), "--prefix", &prefix, "--axis", "7"];
    args.extend(timeout);
    let run = serve_while_running(&prefix, &args);
    let (stdout, stderr) = text(&run.output);
    assert_eq!(run.output.status.code(), Some(3), "{stdout}{stderr}");
    assert!(stdout.contains("refused: there is no axis 7"), "{stdout}");

    // Another layout: iceoryx2 refuses the client when it opens the service (the type name
    // differs), and the example says the contract versions differ.
    let prefix = format!("layout-languages-mismatch-{}", std::process::id());
    let wrapper = format!(
        "import sys, runpy, motion_shm\n\
         motion_shm.MACHINE_STATE_TYPE_NAME = 'motion::MachineState::v0'\n\
         sys.argv = [{example:?}, '--prefix', {prefix:?}, '--timeout', '2']\n\
         runpy.run_path({example:?}, run_name='__main__')\n"
    );
    let run = serve_while_running(&prefix, &["-c", &wrapper]);
    let (stdout, stderr) = text(&run.output);
    assert_eq!(run.output.status.code(), Some(2), "{stdout}{stderr}");
    assert!(stderr.contains("another contract version"), "{stderr}");
    assert!(run.requests.is_empty());
}

#[test]
fn the_example_fails_at_once_without_a_coordinator() {
    if !python_iceoryx2_available() {
        assert!(
            std::env::var("MOTION_REQUIRE_ALL").as_deref() != Ok("1"),
            "the iceoryx2 Python package is not importable and MOTION_REQUIRE_ALL=1"
        );
        {
            use std::io::Write as _;
            let _ = writeln!(
                std::io::stderr(),
                "SKIPPED the_example_fails_at_once_without_a_coordinator: the iceoryx2 Python package \
             is not installed (`pip install iceoryx2==0.10.0`, as .ci/run does)"
            );
        }
        return;
    }
    let prefix = format!("layout-languages-none-{}", std::process::id());
    let started = Instant::now();
    let out = Command::new("python3")
        .args([
            example_path().as_str(),
            "--prefix",
            &prefix,
            "--timeout",
            "30",
        ])
        .env("PYTHONPATH", crate_dir().join("python"))
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .output()
        .expect("running python3");
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1), "{stdout}{stderr}");
    assert!(
        stderr.contains(&format!("no coordinator at '{prefix}'")),
        "{stderr}"
    );
    // Opening a missing service does not wait for the timeout.
    assert!(started.elapsed() < Duration::from_secs(30));
}
