# Bash completion for `esg` (docs/cli.md). Installed by CMake as
# share/bash-completion/completions/esg and printed by `esg completion bash`; to try it from a
# checkout: source deploy/completion/esg.bash
# Completes the verbs, the options of the verb on the line (and the global options), the values
# of --format and --model, file names after the options that take a file, and after --spacecraft
# the ids the server knows (`esg __complete spacecraft`, with the --server, --token and --tls-*
# of the line; nothing when the server is down or refuses the token, within 1 s).

_esg() {
  local cur prev words cword
  # Bash splits words at ':' (COMP_WORDBREAKS), which would cut `--server host:port` in three:
  # keep it one word (bash-completion's -n :, or the line itself split at blanks).
  if declare -F _init_completion >/dev/null; then
    _init_completion -n : || return
  elif [[ -n "${COMP_LINE-}" ]]; then
    local line=${COMP_LINE:0:COMP_POINT}
    read -ra words <<<"$line"
    [[ -z "$line" || "$line" == *[[:blank:]] ]] && words+=("")
    cword=$((${#words[@]} - 1))
    cur="${words[cword]}"
    prev="${words[cword-1]}"
  else
    cur="${COMP_WORDS[COMP_CWORD]}"
    prev="${COMP_WORDS[COMP_CWORD-1]}"
    words=("${COMP_WORDS[@]}")
    cword=$COMP_CWORD
  fi

  local verbs="simulate calibrate gap diagnose diagnoses configure replay status predict alerts history
    estimates export model gyro orbit help version completion"
  local global="--server --token --tls-ca --tls-cert --tls-key --help --version"
  local format="-o --format --json"

  # The verb (and the sub-verb of diagnoses, export, model, gyro and orbit) on the line so far; global options may
  # come first.
  local verb="" sub="" i
  local -a connection=()
  for ((i = 1; i < cword; i++)); do
    case "${words[i]}" in
      --server | --token | --tls-ca | --tls-cert | --tls-key)
        connection+=("${words[i]}" "${words[i+1]}")
        ((i++))
        ;;
      -*) ;;
      *)
        if [[ -z "$verb" ]]; then
          verb="${words[i]}"
        elif [[ ( "$verb" == diagnoses || "$verb" == export || "$verb" == model ||
                  "$verb" == gyro || "$verb" == orbit ) && -z "$sub" ]]; then
          sub="${words[i]}"
        fi
        ;;
    esac
  done

  case "$prev" in
    --format | -o)
      if [[ "$verb" == export ]]; then
        COMPREPLY=($(compgen -W "csv json" -- "$cur"))
      else
        COMPREPLY=($(compgen -W "table json csv" -- "$cur"))
      fi
      return
      ;;
    --model)
      COMPREPLY=($(compgen -W "1 10 11 1+11 10+11 1+10+11" -- "$cur"))
      return
      ;;
    --profile)
      COMPREPLY=($(compgen -W "inertial orbital calibration mixed" -- "$cur"))
      return
      ;;
    --config | --recording | --columns | --scenario | --write-config | --truth | --series-csv | \
      --aem | --planned | --oem | --orbit | --tls-ca | --tls-cert | --tls-key)
      COMPREPLY=($(compgen -f -- "$cur"))
      return
      ;;
    --out)
      COMPREPLY=($(compgen -f -- "$cur"))
      return
      ;;
    --spacecraft)
      local ids
      ids=$(timeout 1 "${words[0]}" "${connection[@]}" __complete spacecraft 2>/dev/null)
      COMPREPLY=($(compgen -W "$ids" -- "$cur"))
      return
      ;;
    --severity)
      COMPREPLY=($(compgen -W "INFO WARNING DISTRESS CRITICAL" -- "$cur"))
      return
      ;;
    --server | --token | --from | --to | --since | --step | --hours | --seed | \
      --start | --gap-start | --id | --ack | --operator | --gyro | --rate | --window | --kd | \
      --page-size | --effects | --alpha | --threads | --diagnosis)
      return  # a value the shell cannot guess
      ;;
  esac

  local opts=""
  case "$verb" in
    "") COMPREPLY=($(compgen -W "$verbs $global" -- "$cur")); return ;;
    help) COMPREPLY=($(compgen -W "$verbs" -- "$cur")); return ;;
    completion) COMPREPLY=($(compgen -W "bash" -- "$cur")); return ;;
    version) return ;;
    simulate) opts="--config --profile --scenario --hours --seed --out --write-config --start
                    --telemetry-step --integration-rate --truth --orbit-out $format" ;;
    calibrate) opts="--config --recording --columns --model --kd --consistency-window $format" ;;
    gap) opts="--config --recording --columns --model --kd --consistency-window --gap-start
               --series-csv $format" ;;
    diagnose) opts="--config --recording --columns --spacecraft --from --to --out --model --alpha
                    --max-effects --threads --integration-rate --effects --orbital-period --orbit $format" ;;
    diagnoses)
      case "$sub" in
        "") COMPREPLY=($(compgen -W "list show cancel-auto" -- "$cur")); return ;;
        list) opts="--spacecraft --page-size $format" ;;
        show) opts="--spacecraft --id $format" ;;
        cancel-auto) opts="--spacecraft $format" ;;
      esac
      ;;
    configure) opts="--config --model --replace $format" ;;
    replay) opts="--recording --columns --spacecraft --rate --from-sequence --window --max-retries
                  --max-lease-wait --allow-rejects --wait --wait-timeout $format" ;;
    status) opts="--spacecraft $format" ;;
    predict) opts="--spacecraft --from --to --step --aem --planned $format" ;;
    alerts) opts="--spacecraft --since --active --severity --include-revised --follow --ack --operator
                  $format" ;;
    history) opts="--spacecraft --gyro --from --to --include-revised $format --csv" ;;
    estimates) opts="--spacecraft --from --to $format --csv" ;;
    export)
      case "$sub" in
        "") COMPREPLY=($(compgen -W "history telemetry" -- "$cur")); return ;;
        history) opts="--spacecraft --gyro --from --to --out -o --format --include-revised" ;;
        telemetry) opts="--spacecraft --from --to --out" ;;
      esac
      ;;
    model)
      case "$sub" in
        "") COMPREPLY=($(compgen -W "apply" -- "$cur")); return ;;
        apply) opts="--spacecraft --diagnosis $format" ;;
      esac
      ;;
    gyro)
      case "$sub" in
        "") COMPREPLY=($(compgen -W "readmit" -- "$cur")); return ;;
        readmit) opts="--spacecraft --gyro --operator $format" ;;
      esac
      ;;
    orbit)
      case "$sub" in
        "") COMPREPLY=($(compgen -W "upload list" -- "$cur")); return ;;
        upload) opts="--spacecraft --oem $format" ;;
        list) opts="--spacecraft $format" ;;
      esac
      ;;
  esac
  COMPREPLY=($(compgen -W "$opts $global" -- "$cur"))
}

complete -F _esg esg
