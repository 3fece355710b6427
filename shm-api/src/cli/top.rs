//! `motion-top`: a terminal UI with a live table of axes and groups and keys for the common
//! commands. Rendering ([`App::render`]) and key handling ([`App::handle_key`]) are pure, so
//! they are tested with ratatui's `TestBackend`; [`run`] owns the terminal and the connection.

use std::time::{Duration, Instant};

use crossterm::event::{self, Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::Line;
use ratatui::widgets::{Block, Paragraph, Row, Table, TableState};

use super::resolve::{axes, groups};
use super::{ClientError, Latched, Machine, Rejected, Target, format, name_str};
use crate::contract::{CommandRequest, MachineState};

/// What the keys act on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Selection {
    /// Nothing selected: every axis.
    All,
    /// An axis row.
    Axis(u16),
    /// A group row.
    Group(u16),
}

/// How the state on screen relates to the coordinator, as the status line says it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Link {
    /// New states arrive.
    Live,
    /// The coordinator is there but published nothing new for this many seconds.
    Stale(u64),
    /// The coordinator went away: the screen shows its last state.
    Gone,
}

/// How long without a new state before the status line says [`Link::Stale`].
pub const STALE_AFTER: Duration = Duration::from_secs(2);

impl Link {
    /// The link when the coordinator is `gone` (its publisher vanished), a state was `seen`,
    /// and the last new one came `quiet` ago.
    pub fn of(gone: bool, seen: bool, quiet: Duration) -> Link {
        if gone {
            Link::Gone
        } else if seen && quiet > STALE_AFTER {
            Link::Stale(quiet.as_secs())
        } else {
            Link::Live
        }
    }
}

/// The UI's state between frames.
#[derive(Debug, Clone)]
pub struct App {
    /// The prefix shown in the status line.
    pub prefix: String,
    /// The selected row.
    pub selection: Selection,
    /// The last command's answer or a connection message.
    pub message: String,
    /// Set by `q`, Esc twice or Ctrl-C.
    pub quit: bool,
}

impl App {
    /// A UI for the coordinator under `prefix`, nothing selected.
    pub fn new(prefix: &str) -> Self {
        Self {
            prefix: prefix.into(),
            selection: Selection::All,
            message: String::new(),
            quit: false,
        }
    }

    fn target(&self) -> Target {
        match self.selection {
            Selection::All => Target::All,
            Selection::Axis(a) => Target::Axis(a),
            Selection::Group(g) => Target::Group(g),
        }
    }

    // Rows in display order: the axes, then the groups.
    fn row_of(&self, state: &MachineState) -> Option<usize> {
        match self.selection {
            Selection::All => None,
            Selection::Axis(a) => Some(usize::from(a)),
            Selection::Group(g) => Some(axes(state).len() + usize::from(g)),
        }
    }

    fn select_row(&mut self, state: &MachineState, row: Option<usize>) {
        let n = axes(state).len();
        self.selection = match row {
            None => Selection::All,
            Some(r) if r < n => u16::try_from(r).map_or(Selection::All, Selection::Axis),
            Some(r) => u16::try_from(r - n).map_or(Selection::All, Selection::Group),
        };
    }

    /// Handles a key; returns the command it asks for. `h` hold, `r` resume, `s` stop,
    /// `a` acknowledge the selection (or all); arrows select; Esc selects all; `q` quits.
    pub fn handle_key(
        &mut self,
        key: KeyEvent,
        state: Option<&MachineState>,
    ) -> Option<CommandRequest> {
        if key.kind == KeyEventKind::Release {
            return None;
        }
        match key.code {
            KeyCode::Char('q') => self.quit = true,
            KeyCode::Char('c') if key.modifiers.contains(KeyModifiers::CONTROL) => self.quit = true,
            KeyCode::Esc => self.selection = Selection::All,
            KeyCode::Down | KeyCode::Up => {
                let state = state?;
                let rows = axes(state).len() + groups(state).len();
                if rows == 0 {
                    return None;
                }
                let next = match (self.row_of(state), key.code) {
                    (None, KeyCode::Down) => Some(0),
                    (None, _) => Some(rows - 1),
                    (Some(r), KeyCode::Down) => Some((r + 1).min(rows - 1)),
                    (Some(0), _) => None,
                    (Some(r), _) => Some(r - 1),
                };
                self.select_row(state, next);
            }
            // Commands need a machine to go to; without one, say so instead.
            KeyCode::Char(c @ ('h' | 'r' | 's' | 'a')) => {
                if state.is_none() {
                    self.message = "not connected".into();
                    return None;
                }
                let t = self.target();
                return Some(match c {
                    'h' => CommandRequest::hold(t),
                    'r' => CommandRequest::resume(t),
                    's' => CommandRequest::stop(t),
                    _ => CommandRequest::acknowledge(t),
                });
            }
            _ => {}
        }
        None
    }

    /// Records a command's answer for the message line.
    pub fn set_answer(&mut self, result: &Result<Latched, Rejected>) {
        self.message = match result {
            Ok(l) => format!("latched in cycle {}", l.cycle),
            Err(e) => format!("rejected: {e}"),
        };
    }

    /// Draws the UI: the status lines, the axes, the groups, the message and the keys. `state`
    /// is `None` while no coordinator was ever seen; `link` says whether it is live, stale or
    /// gone (then `state` is the last one it published).
    pub fn render(&self, frame: &mut Frame, state: Option<&MachineState>, link: Link) {
        let [status, axes_area, groups_area, message, keys] = Layout::vertical([
            Constraint::Length(2),
            Constraint::Min(3),
            Constraint::Length(groups_height(state)),
            Constraint::Length(1),
            Constraint::Length(1),
        ])
        .areas(frame.area());
        frame.render_widget(
            Paragraph::new("h hold  r resume  s stop  a acknowledge  ↑↓ select  Esc all  q quit")
                .style(Style::new().add_modifier(Modifier::DIM)),
            keys,
        );
        frame.render_widget(Paragraph::new(self.message.as_str()), message);
        let Some(state) = state else {
            frame.render_widget(
                Paragraph::new(format!(
                    "motion-top: no coordinator with prefix '{}' — retrying every second (q quits)",
                    self.prefix
                ))
                .style(Style::new().fg(Color::Yellow)),
                status,
            );
            return;
        };
        frame.render_widget(
            Paragraph::new(status_lines(state, &self.prefix, link).to_vec()),
            status,
        );

        // Narrower than 100 columns (an 80-column terminal), the columns marked `false` give way
        // so that the fault stays readable.
        let wide = axes_area.width >= WIDE;
        const AXIS_COLUMNS: [(&str, u16, bool); 8] = [
            ("axis", 10, true),
            ("state", 8, true),
            ("activity", 13, true),
            ("position", 14, true),
            ("setpoint", 12, false),
            ("velocity", 12, false),
            ("homed", 5, true),
            ("fault", 0, true),
        ];
        let keep = AXIS_COLUMNS.map(|(_, _, narrow)| wide || narrow);
        let header = Row::new(pick(AXIS_COLUMNS.map(|(h, _, _)| h), keep))
            .style(Style::new().add_modifier(Modifier::BOLD));
        let rows = axes(state).iter().map(|a| {
            let unit = name_str(&a.unit);
            let row = Row::new(pick(
                [
                    name_str(&a.name).to_string(),
                    format::state_name(a.state).to_string(),
                    format::activity_name(a.activity).to_string(),
                    format!("{} {unit}", format::micro(a.position, 3)),
                    format::micro(a.setpoint, 3),
                    format::micro(a.velocity, 3),
                    format::homed(a).to_string(),
                    format::fault_text(a),
                ],
                keep,
            ));
            if format::is_faulted(a) {
                row.style(Style::new().fg(Color::Red))
            } else {
                row
            }
        });
        let widths = pick(AXIS_COLUMNS.map(|(_, w, _)| width(w)), keep);
        let highlight = Style::new().add_modifier(Modifier::REVERSED);
        let mut axis_sel = TableState::default().with_selected(match self.selection {
            Selection::Axis(a) => Some(usize::from(a)),
            _ => None,
        });
        frame.render_stateful_widget(
            Table::new(rows, widths)
                .header(header)
                .block(Block::bordered().title("axes"))
                .row_highlight_style(highlight),
            axes_area,
            &mut axis_sel,
        );

        // At 80 columns the running record, RC1 and RCC give way.
        let wide = groups_area.width >= WIDE;
        const GROUP_COLUMNS: [(&str, u16, bool); 9] = [
            ("group", 12, true),
            ("axes", 14, true),
            ("chain", 9, true),
            ("record", 7, true),
            ("active", 7, false),
            ("RC1", 4, false),
            ("RCC", 4, false),
            ("activity", 13, true),
            ("override", 0, true),
        ];
        let keep = GROUP_COLUMNS.map(|(_, _, narrow)| wide || narrow);
        let header = Row::new(pick(GROUP_COLUMNS.map(|(h, _, _)| h), keep))
            .style(Style::new().add_modifier(Modifier::BOLD));
        let rows = groups(state).iter().map(|g| {
            Row::new(pick(
                [
                    name_str(&g.name).to_string(),
                    format::members(state, g),
                    format::chain_name(g.chain_state).to_string(),
                    record(g.record),
                    record(g.active_record),
                    flag(g.rc1),
                    flag(g.rcc),
                    format::group_activity_name(g.activity).to_string(),
                    format!("{} %", g.override_percent),
                ],
                keep,
            ))
        });
        let widths = pick(GROUP_COLUMNS.map(|(_, w, _)| width(w)), keep);
        let mut group_sel = TableState::default().with_selected(match self.selection {
            Selection::Group(g) => Some(usize::from(g)),
            _ => None,
        });
        frame.render_stateful_widget(
            Table::new(rows, widths)
                .header(header)
                .block(Block::bordered().title("groups"))
                .row_highlight_style(highlight),
            groups_area,
            &mut group_sel,
        );
    }
}

/// Terminals at least this wide show every column.
const WIDE: u16 = 100;

/// The cells whose `keep` is set, in order.
fn pick<T, const N: usize>(cells: [T; N], keep: [bool; N]) -> Vec<T> {
    cells
        .into_iter()
        .zip(keep)
        .filter_map(|(c, k)| k.then_some(c))
        .collect()
}

/// A column's width: its length, or (0) the rest of the line, at least 10.
fn width(w: u16) -> Constraint {
    if w == 0 {
        Constraint::Min(10)
    } else {
        Constraint::Length(w)
    }
}

fn groups_height(state: Option<&MachineState>) -> u16 {
    let n = state.map_or(0, |s| groups(s).len());
    // Borders and header take three lines.
    u16::try_from(n).unwrap_or(u16::MAX).saturating_add(3)
}

fn record(r: i16) -> String {
    if r < 0 { "-".into() } else { r.to_string() }
}

fn flag(f: u8) -> String {
    if f != 0 { "1".into() } else { "0".into() }
}

/// The two status lines. The first leads with the link when it is not live (`GONE: ...`,
/// `STALE: ...`, so that an 80-column terminal shows it), then the prefix, cycle, period, the
/// last step's compute time and the wake-up lateness; the second the bus counters and the
/// input word.
pub fn status_lines<'a>(state: &MachineState, prefix: &str, link: Link) -> [Line<'a>; 2] {
    let b = &state.bus;
    let times = format!(
        "{prefix}  cycle {}  period {} µs{}  step {} µs  late {} µs",
        state.cycle,
        state.cycle_ns / 1000,
        if state.virtual_time != 0 {
            " (virtual)"
        } else {
            ""
        },
        format::ns_as_us(u64::from(b.step_ns)),
        b.wake_late_us,
    );
    let bus = format!(
        "tx {} rx {} refused {} dropped {} skipped {}  inputs 0x{:08X}",
        b.frames_sent,
        b.frames_received,
        b.tx_refused,
        b.rx_dropped,
        b.skipped_cycles,
        state.inputs,
    );
    let first = match link {
        Link::Live => Line::raw(times),
        Link::Stale(secs) => Line::styled(
            format!("STALE: no new state for {secs} s  {times}"),
            Style::new().fg(Color::Yellow).add_modifier(Modifier::BOLD),
        ),
        Link::Gone => Line::styled(
            format!("GONE: coordinator stopped, last state shown, reconnecting  {times}"),
            Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
        ),
    };
    let second = match link {
        Link::Live => Line::raw(bus),
        _ => Line::styled(bus, Style::new().add_modifier(Modifier::DIM)),
    };
    [first, second]
}

/// Runs the UI until `q`: connects with `connect` (retrying every second while there is no
/// coordinator), draws at about 10 Hz and sends the keys' commands.
pub fn run<M: Machine>(
    prefix: &str,
    mut connect: impl FnMut(&str) -> Result<M, ClientError>,
) -> std::io::Result<()> {
    let mut terminal = ratatui::try_init()?;
    let mut app = App::new(prefix);
    let mut machine: Option<M> = None;
    let mut last_try: Option<Instant> = None;
    let mut shown: Option<Box<MachineState>> = None;
    let mut last_cycle = 0_u64;
    let mut last_change = Instant::now();
    let mut gone = false;
    let result = loop {
        if machine.is_none() && last_try.is_none_or(|t| t.elapsed() >= Duration::from_secs(1)) {
            last_try = Some(Instant::now());
            match connect(prefix) {
                Ok(m) => {
                    machine = Some(m);
                    gone = false;
                    app.message = format!("connected to '{prefix}'");
                    last_change = Instant::now();
                }
                // Gone: the message says so already.
                Err(_) if gone => {}
                Err(e) => app.message = format!("{e}"),
            }
        }
        if machine.as_ref().is_some_and(|m| !m.coordinator_present()) {
            // Its publisher is gone: show the last state as such and reconnect.
            machine = None;
            gone = true;
            app.message = format!("the coordinator under '{prefix}' went away; reconnecting");
        }
        if let Some(s) = machine.as_mut().and_then(|m| m.latest()) {
            if s.cycle != last_cycle {
                last_cycle = s.cycle;
                last_change = Instant::now();
            }
            match shown.as_mut() {
                Some(b) => **b = *s,
                None => shown = Some(Box::new(*s)),
            }
        }
        let link = Link::of(gone, shown.is_some(), last_change.elapsed());
        if matches!(link, Link::Stale(_)) && app.message.starts_with("connected") {
            app.message = format!("no new state from '{prefix}'");
        }
        if let Err(e) = terminal.draw(|f| app.render(f, shown.as_deref(), link)) {
            break Err(e);
        }
        match event::poll(Duration::from_millis(100)) {
            Ok(true) => match event::read() {
                Ok(Event::Key(key)) => {
                    let req = app.handle_key(key, shown.as_deref());
                    match (req, machine.as_mut()) {
                        (Some(req), Some(m)) => {
                            let answer = m.command(&req, Duration::from_millis(500));
                            if matches!(answer, Err(Rejected::Disconnected)) {
                                // Reconnect on the next pass rather than talk to nobody.
                                machine = None;
                                gone = true;
                            }
                            app.set_answer(&answer);
                        }
                        (Some(_), None) => app.message = "not connected".into(),
                        (None, _) => {}
                    }
                }
                Ok(_) => {}
                Err(e) => break Err(e),
            },
            Ok(false) => {}
            Err(e) => break Err(e),
        }
        if app.quit {
            break Ok(());
        }
    };
    ratatui::restore();
    result
}
