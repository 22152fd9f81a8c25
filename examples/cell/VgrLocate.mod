MODULE VgrLocate
  ! VgrLocate.mod -- ABB RAPID client of a vgr cell service's TCP gateway (RobotWare 6/7, option
  ! Socket Messaging). VgrPick sends "LOCATE,<id>,1,<x,y,z,q1,q2,q3,q4>" with the robot's current
  ! CRobT() (mm, quaternion w first), reads the one-line reply
  ! "LOCATE,<id>,<code>,<found>,<x,y,z,q1,q2,q3,q4 of the correction>,...,<status>,<message>"
  ! and moves to PoseMult(correction, taught pose) on code 0 only: any other code, a missing or
  ! unreadable reply stops the program without moving. The line protocol is documented in
  ! plugins/actions/cell/tcp_gateway.py of vgr.
  !
  ! The gateway (the `gateway` settings of `vgr serve RECIPE`) must
  !   - listen where this controller reaches it: VGR_HOST / VGR_PORT below = gateway.listen;
  !   - allow this controller: gateway.allow: ["<controller IP>"] (loopback only otherwise);
  !   - use format "abb" (gateway.format: abb): mm and quaternions q1..q4, as robtargets are.
  ! Ids must be unique (a repeated id gets the remembered reply): nVgrJob is PERS, it survives restarts.
  ! RAPID strings hold 80 characters: the request is sent in pieces and the reply read as rawbytes.
  ! An example, not tested on a robot: check it against the RAPID manual of your RobotWare.

  CONST string VGR_HOST := "192.168.125.50";
  CONST num VGR_PORT := 50010;
  PERS robtarget pPickTaught := [[600,0,50],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
  PERS num nVgrJob := 0;
  VAR socketdev sockVgr;
  VAR rawbytes rawReply;

  PROC VgrPick()
    VAR robtarget pNow;
    VAR robtarget pPick;
    VAR pose poseCorr;
    VAR pose poseTaught;
    VAR pose posePick;
    VAR string sId;
    VAR num nPos;
    VAR num nCode;

    pNow := CRobT(\Tool:=tool0 \WObj:=wobj0);
    nVgrJob := nVgrJob + 1;
    sId := "abb-" + NumToStr(nVgrJob, 0);
    SocketCreate sockVgr;
    SocketConnect sockVgr, VGR_HOST, VGR_PORT \Time:=5;
    SocketSend sockVgr \Str:="LOCATE," + sId + ",1,";
    SocketSend sockVgr \Str:=NumToStr(pNow.trans.x, 3) + "," + NumToStr(pNow.trans.y, 3) + "," + NumToStr(pNow.trans.z, 3) + ",";
    SocketSend sockVgr \Str:=NumToStr(pNow.rot.q1, 6) + "," + NumToStr(pNow.rot.q2, 6) + "," + NumToStr(pNow.rot.q3, 6) + ",";
    SocketSend sockVgr \Str:=NumToStr(pNow.rot.q4, 6) + "\0A";
    ! the capture and the detection take a few hundred ms: wait up to 10 s (one short line, one read)
    SocketReceive sockVgr \RawData:=rawReply \Time:=10;
    SocketClose sockVgr;

    nPos := 1;
    IF NextField(nPos) <> "LOCATE" VgrFail "unexpected reply";
    IF NextField(nPos) <> sId VgrFail "a reply to another request";
    nCode := NumField(nPos);
    IF nCode <> 0 VgrFail "refused, code " + NumToStr(nCode, 0) + " (1 no_part, 2 ambiguous, 3 out_of_limits ...)";
    IF NumField(nPos) < 1 VgrFail "no part found";
    poseCorr.trans.x := NumField(nPos);
    poseCorr.trans.y := NumField(nPos);
    poseCorr.trans.z := NumField(nPos);
    poseCorr.rot.q1 := NumField(nPos);
    poseCorr.rot.q2 := NumField(nPos);
    poseCorr.rot.q3 := NumField(nPos);
    poseCorr.rot.q4 := NumField(nPos);
    poseCorr.rot := NOrient(poseCorr.rot);

    ! the correction left-multiplies the taught pose (both in the base frame)
    poseTaught.trans := pPickTaught.trans;
    poseTaught.rot := pPickTaught.rot;
    posePick := PoseMult(poseCorr, poseTaught);
    pPick := pPickTaught;
    pPick.trans := posePick.trans;
    pPick.rot := NOrient(posePick.rot);
    MoveL Offs(pPick, 0, 0, 50), v200, z10, tool0 \WObj:=wobj0;
    MoveL pPick, v20, fine, tool0 \WObj:=wobj0;
  ERROR
    SocketClose sockVgr;
    VgrFail "socket error " + NumToStr(ERRNO, 0) + ": no reply from the vgr gateway";
  ENDPROC

  ! the next comma-separated field of rawReply from byte nPos on (nPos moves past its comma)
  FUNC string NextField(INOUT num nPos)
    VAR string sChunk;
    VAR num nLen;
    VAR num nComma;

    nLen := RawBytesLen(rawReply) - nPos + 1;
    IF nLen > 80 nLen := 80;
    IF nLen <= 0 RETURN "";
    UnpackRawBytes rawReply, nPos, sChunk \ASCII:=nLen;
    nComma := StrFind(sChunk, 1, ",\0A");
    nPos := nPos + nComma;
    IF nComma = 1 RETURN "";
    RETURN StrPart(sChunk, 1, nComma - 1);
  ENDFUNC

  FUNC num NumField(INOUT num nPos)
    VAR num nValue;

    IF NOT StrToVal(NextField(nPos), nValue) VgrFail "unreadable number in the reply";
    RETURN nValue;
  ENDFUNC

  PROC VgrFail(string sWhy)
    ErrWrite "vgr: no correction, not moving", sWhy;
    EXIT;
  ENDPROC
ENDMODULE
