//! Loading a model: the checks of a parsed model file ([`DriveModel::from_file`]) and
//! the index built from it.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;

use super::*;

fn hex16(model: &str, what: &str, s: &str) -> Result<u16, ModelError> {
    if s.len() == 4
        && s.bytes()
            .all(|c| c.is_ascii_digit() || (b'A'..=b'F').contains(&c))
    {
        if let Ok(v) = u16::from_str_radix(s, 16) {
            return Ok(v);
        }
    }
    Err(ModelError::Invalid {
        model: model.to_string(),
        problem: format!("{what}: {s:?} is not four upper-case hex digits"),
    })
}

fn hex8(model: &str, what: &str, s: &str) -> Result<u8, ModelError> {
    if s.len() == 2
        && s.bytes()
            .all(|c| c.is_ascii_digit() || (b'A'..=b'F').contains(&c))
    {
        if let Ok(v) = u8::from_str_radix(s, 16) {
            return Ok(v);
        }
    }
    Err(ModelError::Invalid {
        model: model.to_string(),
        problem: format!("{what}: {s:?} is not two upper-case hex digits"),
    })
}

fn hex_range(model: &str, what: &str, s: &str) -> Result<RangeInclusive<u16>, ModelError> {
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (hex16(model, what, a)?, hex16(model, what, b)?),
        None => {
            let a = hex16(model, what, s)?;
            (a, a)
        }
    };
    if a > b {
        return Err(ModelError::Invalid {
            model: model.to_string(),
            problem: format!("{what}: range {s} runs backwards"),
        });
    }
    Ok(a..=b)
}

impl DriveModel {
    /// Checks a parsed model file and builds the model.
    pub fn from_file(f: &ModelFile) -> Result<Self, ModelError> {
        let m = f.model.as_str();
        let invalid = |problem: String| ModelError::Invalid {
            model: m.to_string(),
            problem,
        };
        if f.schema_version != 1 {
            return Err(invalid(format!(
                "schema_version {} is not supported (1 is)",
                f.schema_version
            )));
        }
        if f.modes != ["rtu", "ascii"] {
            return Err(invalid(format!(
                "modes must be [\"rtu\", \"ascii\"], found {:?}",
                f.modes
            )));
        }
        let broadcast = hex8(m, "addresses.broadcast", &f.addresses.broadcast)?;
        let first = hex8(m, "addresses.first", &f.addresses.first)?;
        let last = hex8(m, "addresses.last", &f.addresses.last)?;
        if broadcast != 0 || first == 0 || first > last {
            return Err(invalid(format!(
                "addresses: broadcast must be 00 and 01 <= first <= last, found {broadcast:02X} {first:02X}..{last:02X}"
            )));
        }
        let functions = f
            .functions
            .codes
            .iter()
            .map(|c| hex8(m, "functions.codes", c))
            .collect::<Result<Vec<_>, _>>()?;
        let mut exception_codes = Vec::new();
        for e in &f.exception_codes {
            exception_codes.push((hex8(m, "exception_codes", &e.code)?, e.meaning.clone()));
        }
        let mut exceptions = BTreeMap::new();
        for fault in Fault::ALL {
            match f.exceptions.get(fault.key()) {
                Some(rule) => {
                    let code = hex8(m, "exceptions", &rule.code)?;
                    if !exception_codes.iter().any(|(c, _)| *c == code) {
                        return Err(invalid(format!(
                            "exceptions.{}: code {code:02X} is not in the exception-code table",
                            fault.key()
                        )));
                    }
                    check_fact(m, &format!("exceptions.{}", fault.key()), &rule.fact)?;
                    exceptions.insert(
                        fault,
                        ExceptionRule {
                            code,
                            fact: Fact::from_file(&rule.fact),
                        },
                    );
                }
                None if fault == Fault::NoAccess => {}
                None => return Err(invalid(format!("exceptions: no rule for {}", fault.key()))),
            }
        }
        if let Some(k) = f
            .exceptions
            .keys()
            .find(|k| !Fault::ALL.iter().any(|x| x.key() == k.as_str()))
        {
            return Err(invalid(format!("exceptions: unknown fault kind {k:?}")));
        }
        let mut silence = BTreeMap::new();
        for r in SilenceReason::ALL {
            let fact = f
                .silence
                .get(r.key())
                .ok_or_else(|| invalid(format!("silence: no entry for {}", r.key())))?;
            check_fact(m, &format!("silence.{}", r.key()), fact)?;
            silence.insert(r, Fact::from_file(fact));
        }
        if silence.len() != f.silence.len() {
            return Err(invalid("silence: unknown reason".to_string()));
        }

        let l = &f.limits;
        let limits = Limits {
            max_frame: l.max_frame_bytes.value,
            max_frame_fact: Fact::from_file(&l.max_frame_bytes.fact),
            read: PerMode {
                rtu: l.read_registers.rtu,
                ascii: l.read_registers.ascii,
                fact: Fact::from_file(&l.read_registers.fact),
            },
            write: PerMode {
                rtu: l.write_registers.rtu,
                ascii: l.write_registers.ascii,
                fact: Fact::from_file(&l.write_registers.fact),
            },
            same_group: l.same_group.value,
            same_group_fact: Fact::from_file(&l.same_group.fact),
            response_time_ms: l.response_time_ms.value,
            response_time_fact: Fact::from_file(&l.response_time_ms.fact),
        };
        for (what, fact) in [
            ("limits.max_frame_bytes", &l.max_frame_bytes.fact),
            ("limits.read_registers", &l.read_registers.fact),
            ("limits.write_registers", &l.write_registers.fact),
            ("limits.same_group", &l.same_group.fact),
            ("limits.response_time_ms", &l.response_time_ms.fact),
        ] {
            check_fact(m, what, fact)?;
        }
        // Counts must fit the frame: the derivation the legacy note confirms.
        for mode in [Mode::Rtu, Mode::Ascii] {
            let r = limits.read.get(mode);
            let w = limits.write.get(mode);
            let read_len = read_response_len(mode, r);
            let write_len = write_request_len(mode, w);
            if r == 0 || read_len > limits.max_frame {
                return Err(invalid(format!(
                    "limits.read_registers.{mode}: {r} registers need a {read_len}-byte response, over the {}-byte frame",
                    limits.max_frame
                )));
            }
            if w == 0 || write_len > limits.max_frame {
                return Err(invalid(format!(
                    "limits.write_registers.{mode}: {w} registers need a {write_len}-byte request, over the {}-byte frame",
                    limits.max_frame
                )));
            }
        }

        // Groups: command and monitor first, then parameter groups, then examples.
        let mut groups = Vec::new();
        for g in &f.groups {
            let first = hex16(m, "groups.first", &g.first)?;
            let last = hex16(m, "groups.last", &g.last)?;
            groups.push(Group {
                name: g.name.clone(),
                parameter_group: None,
                span: first..=last,
                registers: vec![],
                no_access: vec![],
                source: String::new(),
                notes: vec![],
            });
        }
        let mut map: Vec<(RangeInclusive<u16>, Access, usize, Origin)> = Vec::new();
        let mut named = Vec::new();
        let mut bits = BitRoles::default();
        let mut external_fault_code = None;
        for r in &f.registers {
            let register = hex16(m, "registers.register", &r.register)?;
            let access = Access::parse(&r.access).ok_or_else(|| {
                invalid(format!(
                    "register {register:04X}: access {:?} is not read-write, read-only or reserved",
                    r.access
                ))
            })?;
            let role = match &r.role {
                Some(s) => Some(Role::parse(s).ok_or_else(|| {
                    invalid(format!("register {register:04X}: unknown role {s:?}"))
                })?),
                None => None,
            };
            let group = groups
                .iter()
                .position(|g| g.span.contains(&register))
                .ok_or_else(|| invalid(format!("register {register:04X} is in no group")))?;
            let fact = match (&r.source, r.basis) {
                (Some(s), None) => Fact::documented(s),
                (source, Some(basis)) => {
                    let ff = file::FactFile {
                        basis,
                        source: source.clone(),
                        rule: None,
                        why: r.why.clone(),
                    };
                    check_fact(m, &format!("register {register:04X}"), &ff)?;
                    Fact::from_file(&ff)
                }
                (None, None) => {
                    return Err(invalid(format!(
                        "register {register:04X}: needs a source or a basis"
                    )))
                }
            };
            let max = match &r.max {
                Some(b) => {
                    check_fact(m, &format!("register {register:04X} max"), &b.fact)?;
                    Some((
                        hex16(m, "registers.max", &b.value)?,
                        Fact::from_file(&b.fact),
                    ))
                }
                None => None,
            };
            let resolution = match &r.resolution {
                Some(res) => {
                    check_fact(m, &format!("register {register:04X} resolution"), &res.fact)?;
                    check_fact(
                        m,
                        &format!("register {register:04X} resolution handling"),
                        &res.handling,
                    )?;
                    if res.step < 2 {
                        return Err(invalid(format!(
                            "register {register:04X}: resolution step {} must be 2 or more",
                            res.step
                        )));
                    }
                    Some(Resolution {
                        above: hex16(m, "registers.resolution.above", &res.above)?,
                        step: res.step,
                        fact: Fact::from_file(&res.fact),
                        lines: res.lines.clone(),
                        handling: Fact::from_file(&res.handling),
                    })
                }
                None => None,
            };
            if (max.is_some() || resolution.is_some()) && access != Access::ReadWrite {
                return Err(invalid(format!(
                    "register {register:04X}: a max or resolution needs a read-write register"
                )));
            }
            if let Some(code) = &r.external_fault_code {
                check_fact(m, "external_fault_code", &code.fact)?;
                external_fault_code = Some((code.value, Fact::from_file(&code.fact)));
            }
            for b in &r.bits {
                if b.bit > 15 {
                    return Err(invalid(format!(
                        "register {register:04X}: bit {} is over 15",
                        b.bit
                    )));
                }
                let slot = match (role, b.role.as_deref()) {
                    (_, None) => continue,
                    (Some(Role::Operation), Some("run")) => &mut bits.run,
                    (Some(Role::Operation), Some("reverse")) => &mut bits.reverse,
                    (Some(Role::Operation), Some("external-fault")) => &mut bits.external_fault,
                    (Some(Role::Operation), Some("fault-reset")) => &mut bits.fault_reset,
                    (Some(Role::Status), Some("running")) => &mut bits.running,
                    (Some(Role::Status), Some("reverse")) => &mut bits.status_reverse,
                    (Some(Role::Status), Some("ready")) => &mut bits.ready,
                    (Some(Role::Status), Some("fault")) => &mut bits.fault,
                    (_, Some(other)) => {
                        return Err(invalid(format!(
                            "register {register:04X}: bit role {other:?} is not known for this register"
                        )))
                    }
                };
                *slot = Some(b.bit);
            }
            map.push((register..=register, access, group, Origin::Named));
            named.push(NamedRegister {
                register,
                name: r.name.clone(),
                access,
                role,
                max,
                max_lines: r.max.as_ref().and_then(|b| b.lines.clone()),
                max_notes: r.max.as_ref().map(|b| b.notes.clone()).unwrap_or_default(),
                resolution,
                fact,
            });
        }
        for g in groups.iter_mut() {
            let regs: Vec<u16> = named
                .iter()
                .filter(|n| g.span.contains(&n.register))
                .map(|n| n.register)
                .collect();
            if regs.len() != g.span.clone().count() {
                return Err(invalid(format!(
                    "group {}: {} named registers for a span of {} ({:04X}..{:04X}); every register of the block must be listed",
                    g.name,
                    regs.len(),
                    g.span.clone().count(),
                    g.span.start(),
                    g.span.end()
                )));
            }
            g.registers = vec![g.span.clone()];
            g.source = named
                .iter()
                .find(|n| n.register == *g.span.start())
                .and_then(|n| n.fact.source.clone())
                .unwrap_or_default();
        }
        for p in &f.parameter_groups {
            let idx = groups.len();
            let mut registers = Vec::new();
            for r in &p.registers {
                registers.push(hex_range(m, "parameter_groups.registers", r)?);
            }
            let mut no_access = Vec::new();
            for r in &p.no_access {
                no_access.push(hex_range(m, "parameter_groups.no_access", r)?);
            }
            for r in registers.iter().chain(&no_access) {
                if (*r.start() >> 8) as u8 != p.group || (*r.end() >> 8) as u8 != p.group {
                    return Err(invalid(format!(
                        "parameter group {}: {:04X}..{:04X} is outside the group (register = group x 100H + number)",
                        p.group,
                        r.start(),
                        r.end()
                    )));
                }
            }
            for r in &registers {
                map.push((r.clone(), Access::ReadWrite, idx, Origin::Parameter));
            }
            for r in &no_access {
                map.push((r.clone(), Access::NoAccess, idx, Origin::Parameter));
            }
            let lo = registers.iter().chain(&no_access).map(|r| *r.start()).min();
            let hi = registers.iter().chain(&no_access).map(|r| *r.end()).max();
            let (Some(lo), Some(hi)) = (lo, hi) else {
                return Err(invalid(format!(
                    "parameter group {}: no registers",
                    p.group
                )));
            };
            groups.push(Group {
                name: format!("group {}", p.group),
                parameter_group: Some(p.group),
                span: lo..=hi,
                registers,
                no_access,
                source: p.source.clone(),
                notes: p.notes.clone(),
            });
        }
        let mut example_registers = Vec::new();
        for e in &f.example_registers {
            let register = hex16(m, "example_registers.register", &e.register)?;
            let initial = hex16(m, "example_registers.initial", &e.initial)?;
            let access = Access::parse(&e.access)
                .filter(|a| matches!(a, Access::ReadWrite | Access::ReadOnly))
                .ok_or_else(|| {
                    invalid(format!(
                        "example register {register:04X}: access must be read-write or read-only"
                    ))
                })?;
            check_fact(m, "example_registers", &e.fact)?;
            let idx = groups.len();
            groups.push(Group {
                name: format!("example {register:04X}"),
                parameter_group: None,
                span: register..=register,
                registers: vec![register..=register],
                no_access: vec![],
                source: e.fact.citation_text(),
                notes: vec![],
            });
            map.push((register..=register, access, idx, Origin::Example));
            example_registers.push((register, initial, access, Fact::from_file(&e.fact)));
        }
        map.sort_by_key(|(r, ..)| *r.start());
        for w in map.windows(2) {
            if w[0].0.end() >= w[1].0.start() {
                return Err(invalid(format!(
                    "registers {:04X}..{:04X} and {:04X}..{:04X} overlap",
                    w[0].0.start(),
                    w[0].0.end(),
                    w[1].0.start(),
                    w[1].0.end()
                )));
            }
        }
        let mut aliases = Vec::new();
        for a in &f.aliases {
            let first = hex16(m, "aliases.first", &a.first)?;
            let last = hex16(m, "aliases.last", &a.last)?;
            let target = hex16(m, "aliases.target", &a.target)?;
            check_fact(m, "aliases", &a.fact)?;
            if first > last || u32::from(target) + u32::from(last - first) > 0xFFFF {
                return Err(invalid(format!(
                    "alias {first:04X}..{last:04X} -> {target:04X} is out of range"
                )));
            }
            aliases.push(Alias {
                span: first..=last,
                target,
                fact: Fact::from_file(&a.fact),
            });
        }
        let id = &f.identification;
        check_fact(m, "identification", &id.fact)?;
        let identification = Identification {
            register: id
                .register
                .as_deref()
                .map(|r| hex16(m, "identification.register", r))
                .transpose()?,
            value: id
                .value
                .as_deref()
                .map(|r| hex16(m, "identification.value", r))
                .transpose()?,
            simulated: match (&id.value, &id.simulated) {
                (Some(v), _) | (None, Some(v)) => hex16(m, "identification", v)?,
                (None, None) => 0,
            },
            fact: Fact::from_file(&id.fact),
        };
        let mut initial_values = Vec::new();
        for v in &f.initial_values {
            check_fact(m, "initial_values", &v.fact)?;
            initial_values.push((
                hex16(m, "initial_values.register", &v.register)?,
                hex16(m, "initial_values.value", &v.value)?,
                Fact::from_file(&v.fact),
            ));
        }
        check_fact(m, "parameter_access", &f.parameter_access.fact)?;
        check_fact(m, "addresses", &f.addresses.fact)?;
        check_fact(m, "functions", &f.functions.fact)?;
        check_fact(m, "loop_back", &f.loop_back.fact)?;
        check_fact(
            m,
            "loop_back.other_test_codes",
            &f.loop_back.other_test_codes,
        )?;

        let mut model = DriveModel {
            id: f.model.clone(),
            title: f.title.clone(),
            manual: f.manual.clone(),
            broadcast,
            addresses: first..=last,
            addresses_fact: Fact::from_file(&f.addresses.fact),
            functions,
            functions_fact: Fact::from_file(&f.functions.fact),
            loop_back_data_bytes: f.loop_back.data_bytes,
            loop_back_fact: Fact::from_file(&f.loop_back.fact),
            loop_back_other_fact: Fact::from_file(&f.loop_back.other_test_codes),
            exception_codes,
            exception_codes_source: f.exception_codes_source.clone(),
            exceptions,
            silence,
            limits,
            groups,
            named,
            bits,
            external_fault_code,
            identification,
            parameter_access: Fact::from_file(&f.parameter_access.fact),
            parameter_read_only: Vec::new(),
            example_registers,
            initial_values,
            aliases,
            source: Source::default(),
            map,
        };
        model.parameter_read_only = read_only_parameters(&model, &f.parameter_access.read_only)?;
        for (r, ..) in &model.initial_values {
            if model.lookup(*r).is_none() {
                return Err(invalid(format!(
                    "initial value for {r:04X}, which is not in the map"
                )));
            }
        }
        if let Some(r) = model.identification.register {
            if model.lookup(r).is_none() {
                return Err(invalid(format!(
                    "identification register {r:04X} is not in the map"
                )));
            }
        }
        Ok(model)
    }
}

impl file::FactFile {
    fn citation_text(&self) -> String {
        Fact::from_file(self).citation()
    }
}

/// "12-16" as (group, number).
fn parameter_number(s: &str) -> Option<(u8, u8)> {
    let (g, n) = s.split_once('-')?;
    let ok = |t: &str| !t.is_empty() && t.len() <= 2 && t.bytes().all(|c| c.is_ascii_digit());
    if !ok(g) || !ok(n) {
        return None;
    }
    Some((g.parse().ok()?, n.parse().ok()?))
}

/// Checks the read-only entries against the map built so far: every register a listed
/// parameter (not "-"), the parameter numbers spelling the same registers, no overlaps.
fn read_only_parameters(
    model: &DriveModel,
    entries: &[file::ReadOnlyParameterFile],
) -> Result<Vec<ReadOnlyParameter>, ModelError> {
    let m = model.id.as_str();
    let invalid = |problem: String| ModelError::Invalid {
        model: m.to_string(),
        problem,
    };
    let mut out: Vec<ReadOnlyParameter> = Vec::new();
    for e in entries {
        let what = format!("parameter_access.read_only {}", e.registers);
        let registers = hex_range(m, "parameter_access.read_only.registers", &e.registers)?;
        check_fact(m, &what, &e.fact)?;
        let (a, b) = match e.parameters.split_once("..") {
            Some((a, b)) => (a, b),
            None => (e.parameters.as_str(), e.parameters.as_str()),
        };
        let spelled = parameter_number(a)
            .zip(parameter_number(b))
            .map(|((ga, na), (gb, nb))| {
                (u16::from(ga) << 8 | u16::from(na))..=(u16::from(gb) << 8 | u16::from(nb))
            });
        if spelled.as_ref() != Some(&registers) {
            return Err(invalid(format!(
                "{what}: parameters {:?} are not registers {:04X}..{:04X} (register = group x 100H + number)",
                e.parameters,
                registers.start(),
                registers.end()
            )));
        }
        for r in registers.clone() {
            let i = model.map.partition_point(|(x, ..)| *x.end() < r);
            match model.map.get(i) {
                Some((x, Access::ReadWrite, _, Origin::Parameter)) if x.contains(&r) => {}
                _ => {
                    return Err(invalid(format!(
                        "{what}: {r:04X}H is not a listed parameter register of the map"
                    )))
                }
            }
        }
        if let Some(o) = out.iter().find(|o| {
            o.registers.start() <= registers.end() && registers.start() <= o.registers.end()
        }) {
            return Err(invalid(format!("{what}: overlaps {}", o.parameters)));
        }
        out.push(ReadOnlyParameter {
            registers,
            parameters: e.parameters.clone(),
            fact: Fact::from_file(&e.fact),
            lines: e.lines.clone(),
        });
    }
    Ok(out)
}

fn check_fact(model: &str, what: &str, f: &file::FactFile) -> Result<(), ModelError> {
    let problem = match f.basis {
        Basis::Documented if f.source.as_deref().unwrap_or("").is_empty() => {
            Some("a documented fact needs a source")
        }
        Basis::Derived if f.rule.as_deref().unwrap_or("").is_empty() => {
            Some("a derived fact needs a rule")
        }
        Basis::Decision if f.why.as_deref().unwrap_or("").is_empty() => {
            Some("a decision needs a why")
        }
        _ => None,
    };
    match problem {
        Some(p) => Err(ModelError::Invalid {
            model: model.to_string(),
            problem: format!("{what}: {p}"),
        }),
        None => Ok(()),
    }
}
